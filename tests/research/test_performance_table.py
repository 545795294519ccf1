"""The performance table labels every line with the sizes of its own bench row."""

from experiments.performance import _lines


def test_each_line_carries_its_own_rows_sizes():
    rows = [{"bench": "stereo.sgm", "threads": 2, "height": h, "width": w, "disparities": 64, "total_s": t,
             "ref": "cv2", "ref_total_s": t / 10, "speedup_total": 0.1}
            for h, w, t in ((256, 256, 0.05), (500, 741, 0.5))]
    lines = [line for row in rows for line in _lines(row)]
    assert [ln["sizes"] for ln in lines] == ["height=256, width=256, disparities=64",
                                             "height=500, width=741, disparities=64"]
    assert [ln["ref_s"] for ln in lines] == [0.005, 0.05]
