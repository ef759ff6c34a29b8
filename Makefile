# The two commands: `make demo` and `make test`. Each sets up everything on a fresh machine.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# make demo installs the product only; make test adds the test tools and PyTorch (the training extra).
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test
# Debian packages a later stage needs (offscreen GL for pyrender via EGL/Mesa, ffmpeg-free video via OpenCV).
APT_PACKAGES := libegl1 libgl1 libgles2 libegl-mesa0 libgl1-mesa-dri
# the viewer's page is tested in a real browser (Debian's headless Chromium); only make test needs it
TEST_APT_PACKAGES := chromium chromium-driver

# MediaPipe Pose, the peer the benchmarks compare with, in its own environment: its last wheel that
# bundles the pose models needs numpy<2, opencv-python-headless<4.12 and protobuf<5.
PEERS := .venv-peers
PEERS_STAMP := $(PEERS)/.installed
# NVIDIA Warp, whose CPU cloth benchmark the cloth bench runs beside its own free sheet (its wheel
# carries its own compiler; kept out of the product's environment).
WARP := .venv-warp
WARP_STAMP := $(WARP)/.installed

.PHONY: demo test lint bench bench-peers bench-warp clean-venv apt

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e .
	@touch $(STAMP)

$(TEST_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install -q -e '.[dev,train]'
	@touch $(TEST_STAMP)

apt:
	@missing=""; for p in $(APT_PACKAGES) $(EXTRA_APT); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq $$missing >/dev/null; \
	fi

demo: $(STAMP) apt
	$(BIN)/python -m tracker_service demo

# pytest exits 5 when it collects no test: report it plainly instead of failing with make's code 2.
test: EXTRA_APT = $(TEST_APT_PACKAGES)
test: $(TEST_STAMP) apt
	@$(BIN)/python -m pytest -q $(PYTEST_ARGS); rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest: no tests were collected"; exit 0; fi; exit $$rc

lint: $(TEST_STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

bench: $(TEST_STAMP) apt
	$(BIN)/python bench/run_all.py

$(PEERS_STAMP):
	@test -x $(PEERS)/bin/python || $(PY) -m venv $(PEERS)
	$(PEERS)/bin/python -m pip install -q "mediapipe==0.10.21" "numpy<2" "opencv-python-headless<4.12" "protobuf<5"
	@touch $(PEERS_STAMP)

bench-peers: $(TEST_STAMP) $(PEERS_STAMP) apt
	$(BIN)/python bench/bench_peers.py $(PEERS_ARGS)

$(WARP_STAMP):
	@test -x $(WARP)/bin/python || $(PY) -m venv $(WARP)
	$(WARP)/bin/python -m pip install -q "warp-lang==1.19.0" numpy
	@touch $(WARP_STAMP)

# the cloth solver's speed beside Warp's, one core (about 1.5 minutes)
bench-warp: $(STAMP) $(WARP_STAMP) apt
	taskset -c 0 $(BIN)/python bench/bench_cloth.py --skip-sweep --jobs 1 --warp-python $(WARP)/bin/python $(WARP_ARGS)

clean-venv:
	rm -rf $(VENV) $(PEERS) $(WARP)
