"""Datasets: Mitsuba ground truth (built-in scenes, the generator and the loader) and readers of the
field's benchmark formats (Blender/NeRF-synthetic, COLMAP and Mip-NeRF 360, LLFF, Middlebury, KITTI and
ETH3D stereo, Sintel, KITTI and Middlebury flow), all returning the same objects.

    from research.datasets import DatasetConfig, generate, load
    generate(DatasetConfig("objects", views=100, res=256, spp=64), "data/objects")
    ds = load("data/objects"); train = ds.load_split("train")   # verified against manifest.json
"""

from research.datasets.generate import (CACHE_ROOT_HELP, DatasetConfig, cache_dir, ensure, generate,
                                       provenance)
from research.datasets.loader import (Dataset, DatasetError, FlowSequence, Protocol, StereoPair, load, load_flow,
                                      load_stereo)
from research.datasets.blender import load_blender
from research.datasets.colmap import load_colmap
from research.datasets.llff import load_llff
from research.datasets.formats import FORMATS, detect_format, open_dataset
from research.datasets.scenes import SCENES, SceneSpec, get_scene
from research.datasets.flow_benchmarks import (FlowBenchmark, detect_format as detect_flow_format,
                                               load_flow_benchmark, open_benchmark as open_flow_benchmark)
from research.datasets.integrity import verify
from research.datasets.stereo_benchmarks import (detect_format as detect_stereo_format, load_benchmark as
                                                 load_stereo_benchmark, load_eth3d, load_kitti as load_kitti_stereo,
                                                 load_middlebury)

__all__ = ["CACHE_ROOT_HELP", "DatasetConfig", "cache_dir", "ensure", "generate", "provenance", "Dataset",
           "DatasetError", "FlowSequence", "Protocol", "StereoPair", "load_blender", "load_colmap", "load_llff",
           "FORMATS", "detect_format", "open_dataset", "load", "load_flow", "load_stereo", "SCENES", "SceneSpec",
           "get_scene", "verify", "FlowBenchmark", "detect_flow_format", "load_flow_benchmark", "open_flow_benchmark",
           "detect_stereo_format", "load_stereo_benchmark", "load_eth3d", "load_kitti_stereo", "load_middlebury"]
