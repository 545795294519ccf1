# drlab: `make reproduce` and `make test` each set themselves up on a fresh machine:
# a virtualenv in .venv, `pip install -e .[dev]`, and Debian's libllvm19 when
# Dr.Jit cannot load LLVM 17 or newer (falling back to Mitsuba's scalar_rgb with
# a warning if even that fails).

PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.drlab-installed

.PHONY: setup test test-avx2 reproduce reproduce-quick gradcheck bench clean-venv

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(VPY) || $(PYTHON) -m venv $(VENV)
	$(VPY) -m pip install --quiet --upgrade pip
	$(VPY) -m pip install --quiet -e '.[dev]'
	# trackeval is the tests' reference for HOTA. It lists opencv-python (the GUI build, which needs
	# libGL and shares its cv2/ folder with our opencv-python-headless) although the HOTA and
	# MOTChallenge code never imports cv2, so it is installed without its dependencies.
	$(VPY) -m pip install --quiet --no-deps 'trackeval>=1.3'
	$(VPY) -m research.mitsuba_env --ensure
	touch $(STAMP)

# The kernel tests of every route that kernels.fast_paths switches, run a second time with the CPU fast
# paths off: the plain Warp kernels (the CUDA route) on the CPU (docs/kernels.md, "CPU fast paths").
# The adcensus cost is left out: its C++ sits inside its Warp kernel, with its own portable branch.
PLAIN_TESTS := tests/kernels/test_fast_paths.py tests/kernels/test_volume_composite.py \
	tests/kernels/test_reliability_volume_composite.py tests/kernels/test_volume_render.py \
	tests/kernels/test_volume_fields.py tests/kernels/test_corr.py tests/kernels/test_corr_stored.py \
	tests/kernels/test_splat.py tests/kernels/test_splat_tiles.py tests/kernels/test_stereo.py \
	tests/kernels/test_ssim.py

# The suite runs in one pytest-xdist worker per core, at most 4 (`make test TEST_WORKERS=0` runs it in
# one process). --dist loadfile keeps each test module in one worker, so a module's fixtures (the one
# local Ray instance, a rendered scene) are made once and its tests never run beside each other.
TEST_WORKERS ?= $(shell n=$$(nproc 2>/dev/null || echo 1); [ "$$n" -gt 4 ] && n=4; echo $$n)
XDIST := -n $(TEST_WORKERS) --dist loadfile

test: $(STAMP)
	$(VPY) -m pytest -q $(XDIST)
	DRLAB_FAST_PATHS=0 $(VPY) -m pytest -q $(XDIST) $(PLAIN_TESTS) -k "not adcensus"

# `make test` as on an AVX2-only CPU (AMD Zen 3: AVX2 and FMA, no AVX-512), run on a machine that has
# AVX-512: Warp's kernels and the C++ fast paths compiled for znver3 (kernels/cpu_target.py), OpenBLAS
# on its Zen (Haswell) kernels, NumPy's SIMD dispatch without its AVX-512 loops. Dr.Jit and Mitsuba
# still compile for the host (docs/warp.md, "Testing as on another CPU").
AVX2_ENV := DRLAB_CPU_TARGET=znver3 OPENBLAS_CORETYPE=Zen
AVX2_ENV += $(if $(shell grep -m1 -ow avx512f /proc/cpuinfo 2>/dev/null),NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR")

test-avx2: $(STAMP)
	$(AVX2_ENV) $(VPY) -m pytest -q $(XDIST)
	$(AVX2_ENV) DRLAB_FAST_PATHS=0 $(VPY) -m pytest -q $(XDIST) $(PLAIN_TESTS) -k "not adcensus"

reproduce: $(STAMP)
	$(VENV)/bin/drlab reproduce

reproduce-quick: $(STAMP)
	$(VENV)/bin/drlab reproduce --quick

gradcheck: $(STAMP)
	$(VENV)/bin/drlab gradcheck

bench: $(STAMP)
	$(VENV)/bin/drlab bench

clean-venv:
	rm -rf $(VENV)
