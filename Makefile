# dvnav — common tasks. `make test` is what CI runs (.ci/run).
CARGO ?= cargo

.PHONY: all build release test test-learning check-mcap check-deploy test-multihost test-ros2 python test-python bench-peers lint fmt bench torch-venv train heldout heldout-long cuda-toolkit build-cuda gpu-bin gpu-check clean

all: build

build:
	$(CARGO) build --workspace --all-targets

release:
	$(CARGO) build --release

# Unit tests of every crate plus the end-to-end smoke test (learner + 2 actor processes).
# One candle thread in tests: its spin-barrier CPU pool is several times slower on 2 busy cores.
test:
	CANDLE_NUM_THREADS=1 $(CARGO) test --workspace --all-targets
	CANDLE_NUM_THREADS=1 $(CARGO) test --workspace --doc

# The SAC learning test with a known answer: pendulum swing-up to a mean return >= -250 within
# 20,000 steps (learner/tests/sac/pendulum.rs; each run stops at the bar, ~10,600 steps), in fp32
# and in bf16 (`learner.precision`), the two side by side on the 2 cores: ~3 min on the 2-core
# dev machine; too slow for `make test`, so CI runs it after. One candle thread: its spin-barrier pool and rayon matmuls
# made the same test 8x slower on a busy 2-core machine.
test-learning:
	# --workspace (not -p): the same feature set as `make test`, so nothing is rebuilt.
	CANDLE_NUM_THREADS=1 RAYON_NUM_THREADS=1 $(CARGO) test --workspace --test sac -- --ignored --nocapture pendulum

# An independent reader of the MCAP episode logs: the Python `mcap` and `mcap-protobuf-support`
# packages (in a venv under target/) decode every message of a fresh ~3 s run that logs every
# episode (scripts/check_mcap.py), then of a run whose actor-0 is SIGKILLed mid-run: its
# unfinished files read as a stream, every complete episode in them decoded
# (scripts/check_mcap_killed.sh). Skips, exit 0, when python3 with venv is not installed.
PYTHON ?= python3
# The checks below run target/debug/dvnav. Built with the workspace's test targets, so it has
# the same features as `make test`'s (dev-dependencies such as tokio's test-util count) and is a
# no-op after it; `--bin dvnav` alone would rebuild tokio and everything above it.
DVNAV_BIN := --workspace --all-targets
PYENV := target/pyenv
CHECK_RUN := target/check-mcap/run
check-mcap:
	@if ! command -v $(PYTHON) >/dev/null 2>&1 || ! $(PYTHON) -c 'import venv, ensurepip' >/dev/null 2>&1; then \
		echo "check-mcap: SKIPPED: no $(PYTHON) with the venv module; the independent MCAP check did not run"; \
		exit 0; \
	fi; \
	set -e; \
	[ -x $(PYENV)/bin/python ] || $(PYTHON) -m venv $(PYENV); \
	$(PYENV)/bin/pip install --quiet --disable-pip-version-check -r scripts/requirements.txt; \
	$(CARGO) build $(DVNAV_BIN); \
	rm -rf $(CHECK_RUN); \
	./target/debug/dvnav train --actors 2 --config scripts/check_mcap.toml --out $(CHECK_RUN) --progress-every-s 60; \
	./target/debug/dvnav inspect $(CHECK_RUN) --check | tail -n 1; \
	$(PYENV)/bin/python scripts/check_mcap.py $(CHECK_RUN); \
	bash scripts/check_mcap_killed.sh ./target/debug/dvnav $(PYENV)/bin/python $(CHECK_RUN)-killed

# deploy/ against the code (scripts/check_deploy.py): the Kubernetes manifests parse, every flag
# they and the systemd units pass is in `dvnav learner/actor --help`, the probe paths are routed
# by the learner's HTTP server, ports, Services, volumes and the Dockerfile fit together. Python
# 3.11+ with PyYAML (installed into a venv under target/ when the system has none); skips, exit
# 0, without python3.
check-deploy:
	@if ! command -v $(PYTHON) >/dev/null 2>&1 || ! $(PYTHON) -c 'import tomllib' >/dev/null 2>&1; then \
		echo "check-deploy: SKIPPED: no $(PYTHON) 3.11+; deploy/ was not checked"; \
		exit 0; \
	fi; \
	set -e; \
	$(CARGO) build $(DVNAV_BIN); \
	if $(PYTHON) -c 'import yaml' >/dev/null 2>&1; then py=$(PYTHON); else \
		[ -x $(PYENV)/bin/python ] || $(PYTHON) -m venv $(PYENV); \
		$(PYENV)/bin/pip install --quiet --disable-pip-version-check pyyaml; \
		py=$(PYENV)/bin/python; \
	fi; \
	$$py scripts/check_deploy.py ./target/debug/dvnav

# The multi-host test (issue 8): learner and two actors in three network namespaces joined by
# veth links, training over real addresses; the link to one actor is cut for 20 s and restored,
# and the run must carry on (reconnect, every sent transition received once). Needs root for
# `ip netns`; skips, exit 0, where namespaces cannot be made. ~100 s.
test-multihost:
	$(CARGO) build $(DVNAV_BIN)
	bash scripts/multihost.sh target/debug/dvnav

# The ROS 2 bridge (deploy/ros2/) and `dvnav replay`: the bridge's message conversion and control
# cycle with real ROS 2 message classes and CDR from the `rosbags` package, against a real
# `dvnav serve`; replay over rosbag2 MCAP bags the tests write with `rosbags`. Packages in a venv
# under target/ (deploy/ros2/requirements-test.txt); rclpy itself is not needed. Skips, exit 0,
# without python3 and its venv module.
ROS2_PYENV := target/pyenv-ros2
test-ros2:
	@if ! command -v $(PYTHON) >/dev/null 2>&1 || ! $(PYTHON) -c 'import venv, ensurepip' >/dev/null 2>&1; then \
		echo "test-ros2: SKIPPED: no $(PYTHON) with the venv module; the bridge and replay tests did not run"; \
		exit 0; \
	fi; \
	set -e; \
	[ -x $(ROS2_PYENV)/bin/python ] || $(PYTHON) -m venv $(ROS2_PYENV); \
	$(ROS2_PYENV)/bin/pip install --quiet --disable-pip-version-check -r deploy/ros2/requirements-test.txt; \
	deploy/ros2/gen_proto.sh $(ROS2_PYENV)/bin/python; \
	$(CARGO) build $(DVNAV_BIN); \
	cd deploy/ros2 && DVNAV_BIN=$(CURDIR)/target/debug/dvnav ../../$(ROS2_PYENV)/bin/python -m pytest -q -p no:cacheprovider tests

# The Python package (python/, PyO3 + maturin): `import dvnav`, gymnasium.make("dvnav/Nav-v0"),
# dvnav.Policy. Builds it optimized into the venv .venv (python3 -m venv), with numpy and
# gymnasium; use it with `.venv/bin/python` or `source .venv/bin/activate`.
VENV := .venv
python:
	[ -x $(VENV)/bin/python ] || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet --disable-pip-version-check -r python/requirements.txt
	cd python && VIRTUAL_ENV=$(CURDIR)/$(VENV) PATH=$(CURDIR)/$(VENV)/bin:$$PATH maturin develop --release --quiet

# The package's tests (python/tests: Gymnasium conformance, determinism, the vector env against
# single envs, `dvnav eval`'s episodes replayed step for step, the policy, the README's examples)
# in their own venv under target/, with pytest and Stable-Baselines3 (PyTorch, ~3 GB once). The
# extension is the one `make test` built (target/debug/lib_core.so, the workspace's one feature
# set, unoptimized crates beside optimized dependencies): installed with the package's Python
# files into the venv's site-packages, not rebuilt by maturin, whose `cargo rustc` of the one
# crate resolves other features and rebuilt candle and everything above it (~6 of its 8 min
# in a clean CI run). pytest runs as the venv's `pytest` script, not `python -m pytest`, which
# would put python/ (the package's sources, without the extension) first on the path.
# `make python` is how users build it (maturin, optimized). Skips, exit 0, without python3 and
# its venv module.
PY_TEST_ENV := target/pyenv-python
test-python:
	@if ! command -v $(PYTHON) >/dev/null 2>&1 || ! $(PYTHON) -c 'import venv, ensurepip' >/dev/null 2>&1; then \
		echo "test-python: SKIPPED: no $(PYTHON) with the venv module; the Python package was not tested"; \
		exit 0; \
	fi; \
	set -e; \
	[ -x $(PY_TEST_ENV)/bin/python ] || $(PYTHON) -m venv $(PY_TEST_ENV); \
	$(PY_TEST_ENV)/bin/pip install --quiet --disable-pip-version-check -r python/requirements-test.txt; \
	$(CARGO) build $(DVNAV_BIN); \
	$(PY_TEST_ENV)/bin/python scripts/install_python_ext.py target/debug/lib_core.so python/dvnav; \
	cd python && DVNAV_BIN=$(CURDIR)/target/debug/dvnav ../$(PY_TEST_ENV)/bin/pytest -q -p no:cacheprovider tests

# dvnav beside Stable-Baselines3 on this machine (scripts/bench_peers.py): env steps/s through
# Python, and time to skill of `dvnav train` against SB3's SAC with the same network and
# curriculum, 3 seeds each, alternated. ~1 h on 2 cores. Writes runs/peers/peers.json.
bench-peers: release python
	$(VENV)/bin/pip install --quiet --disable-pip-version-check -r python/requirements-test.txt
	$(VENV)/bin/python scripts/bench_peers.py ./target/release/dvnav --out runs/peers $(PEERS_ARGS)

# Crate layering and no import loops inside a crate (scripts/check_layers.py; Python 3.11+).
lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	$(PYTHON) scripts/check_layers.py

fmt:
	$(CARGO) fmt --all

# Figures as JSON lines: environment steps/s, transport, SAC updates/s and policy latency (fp32
# beside PyTorch, then bf16: `bf16_kernel` says whether this CPU has AVX512-BF16), and the
# DVST controller's command latency at batch 1 over loopback gRPC (`dvnav serve`, target p99 < 2 ms).
bench: release
	./target/release/dvnav bench env --json
	./target/release/dvnav bench transport --json
	./target/release/dvnav bench replay --json
	./target/release/dvnav bench learner --batch 256 --torch --json
	./target/release/dvnav bench learner --batch 128 --torch --json
	./target/release/dvnav bench learner --batch 256 --precision bf16 --json
	./target/release/dvnav bench learner --batch 128 --precision bf16 --json
	./target/release/dvnav bench serve --json
	./target/release/dvnav bench plan --json

# Python with PyTorch for the comparison in `make bench` (optional, ~3 GB download).
torch-venv:
	python3 -m venv .venv && .venv/bin/pip install torch numpy

# The held-out suite (issues 14, 29): local tasks (2-5 m, path <= 1.5x) in generated rooms at seeds
# 9000+ of every kind and the real-building maps in maps/, at R = 0.2-0.6 m (DVST), clean and noisy
# (scripts/heldout_suite.py). ~8 min on 2 cores with the defaults below. HELDOUT_ARGS="--checkpoint runs/x/checkpoints/ckpt-N" for another agent.
HELDOUT_ARGS ?= --checkpoint models/meta-r0.2 --episodes 20 --map-episodes 50
heldout: release
	$(PYTHON) scripts/heldout_suite.py --dvnav ./target/release/dvnav $(HELDOUT_ARGS) --tasks local --out runs/heldout/suite.json

# The long-task suites (issue 28): goals 5-10 m away by any route, with the planner's subgoals and
# mapless, clean and noisy; ~25 min on 2 cores. Figures: docs/results.md, "Through a whole building".
heldout-long: release
	$(PYTHON) scripts/heldout_suite.py --dvnav ./target/release/dvnav $(HELDOUT_ARGS) --tasks long --out runs/heldout/long.json

# The CUDA toolkit that the `cuda` feature builds with: CUDA 13.0's nvcc, headers, cuBLAS,
# cuRAND, NVRTC and runtime from PyPI into .venv-cuda/ (~700 MB download once), and a stub
# libcuda to link against (scripts/cuda_toolkit.sh). No GPU, driver or system CUDA needed. By
# hand: `eval "$$(scripts/cuda_toolkit.sh)"`.
cuda-toolkit:
	scripts/cuda_toolkit.sh >/dev/null

# dvnav with the learner on an NVIDIA GPU (`--device cuda`), built against that toolkit into
# target/cuda/ (target/release/ stays the CPU build). It links on a machine without a GPU and
# runs where an NVIDIA driver >= 580 (CUDA 13.0) is. CUDA_COMPUTE_CAP: nvidia-smi's, else 80.
# Then `--version` with the stub driver: the binary links and starts.
# CUDA_PROFILE=cuda-check (CI): the same build unoptimized, to check that it compiles and links.
CUDA_TARGET := target/cuda
CUDA_PROFILE ?= release
build-cuda:
	@set -e; exports=$$(scripts/cuda_toolkit.sh); eval "$$exports"; \
	$(CARGO) build --profile $(CUDA_PROFILE) --features cuda --target-dir $(CUDA_TARGET) --bin dvnav; \
	LD_LIBRARY_PATH="$$CUDA_ROOT/lib/stubs:$$LD_LIBRARY_PATH" ./$(CUDA_TARGET)/$(CUDA_PROFILE)/dvnav --version

# For a GPU machine with no Rust or no network (the `device` tool's): the CUDA build, stripped,
# in target/gpu/dvnav, to carry there and run as `bash scripts/gpu_check.sh --bin target/gpu/dvnav`.
gpu-bin: CUDA_PROFILE = release
gpu-bin: build-cuda
	mkdir -p target/gpu
	strip -o target/gpu/dvnav $(CUDA_TARGET)/release/dvnav

# On a machine with an NVIDIA GPU (scripts/gpu_check.sh): the CUDA build (or
# GPU_CHECK_ARGS="--bin PATH"), `dvnav bench learner --device cuda --json` at batch 256 and 128
# (and bf16 at 256) alternated with PyTorch on the same GPU where python3 has a CUDA torch,
# `dvnav train --device cuda --stop-when-skilled` for up to 5 minutes, and the figures in
# ${OUT:-runs/gpu-check}/.
gpu-check:
	bash scripts/gpu_check.sh $(GPU_CHECK_ARGS)

# Train with the default config: a learner plus 2 actors on this machine.
train: release
	./target/release/dvnav train --actors 2

clean:
	$(CARGO) clean
