# drlab: `make reproduce` and `make test` each set themselves up on a fresh machine:
# a virtualenv in .venv, `pip install -e .[dev]`, and Debian's libllvm19 when
# Dr.Jit cannot load LLVM 17 or newer (falling back to Mitsuba's scalar_rgb with
# a warning if even that fails).

PYTHON ?= python3
VENV   := .venv
VPY    := $(VENV)/bin/python
STAMP  := $(VENV)/.drlab-installed

.PHONY: setup test reproduce reproduce-quick gradcheck bench clean-venv

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

test: $(STAMP)
	$(VPY) -m pytest -q

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
