# One-command set-up and run. `make test` and `make demo` install everything they need
# (system packages when run as root, a .venv with the project and its dependencies), then run.

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# System libraries the Python wheels load at run time (open3d needs libusb; numba/torch libgomp), and the
# compilers with which nodes.ros_interfaces builds the ROS 2 message packages that have no wheel.
APT_PACKAGES := libusb-1.0-0 libgomp1 cmake g++

.PHONY: test test-all lint demo bench gpu-check setup system-deps clean

test: $(STAMP)
	$(BIN)/python -m pytest

test-all: $(STAMP)
	$(BIN)/python -m pytest -m ""

lint: $(STAMP)
	$(BIN)/ruff check .

demo: $(STAMP)
	rm -rf out/demo
	$(BIN)/pegasus demo-loop --out out/demo

bench: $(STAMP)
	$(BIN)/python benchmarks/render.py
	$(BIN)/python benchmarks/assets.py
	$(BIN)/python benchmarks/generate.py
	$(BIN)/python benchmarks/dope.py
	$(BIN)/python benchmarks/scan.py
	$(BIN)/python benchmarks/robot.py
	$(BIN)/python benchmarks/training.py --work out/bench-training --tag demo-recipe --recipe demo
	$(BIN)/python benchmarks/loop.py

# on a machine with a CUDA GPU: the cuda extra (gsplat), every gpu-marked test and the GPU figures in one table
gpu-check: $(STAMP)
	$(BIN)/python -m pip install -q -e '.[test,ros,cuda]'
	$(BIN)/python benchmarks/gpu_check.py

setup: $(STAMP)

system-deps:
	@missing=""; for p in $(APT_PACKAGES); do \
	  dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = "0" ]; then \
	  echo "installing system packages:$$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing; \
	else \
	  echo "NOTE: system packages missing:$$missing"; \
	  echo "      not root, so not installing them; run: sudo apt-get install$$missing"; \
	fi

$(STAMP): pyproject.toml setup.py setup.cfg | system-deps
	@$(PYTHON) -c 'import sys; assert sys.version_info >= (3, 10), "Python >= 3.10 needed, found " + sys.version' \
	  || { echo "ERROR: $(PYTHON) is too old; set PYTHON=python3.11"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test,ros]' && $(BIN)/python -m nodes.ros_interfaces
	touch $(STAMP)

clean:
	rm -rf $(VENV) out .pytest_cache
