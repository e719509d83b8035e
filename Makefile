# dvnav — common tasks. `make test` is what CI runs (.ci/run).
CARGO ?= cargo

.PHONY: all build release test lint fmt bench train clean

all: build

build:
	$(CARGO) build --workspace --all-targets

release:
	$(CARGO) build --release

# Unit tests of every crate plus the end-to-end smoke test (learner + 2 actor processes).
test:
	$(CARGO) test --workspace --all-targets
	$(CARGO) test --workspace --doc

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings

fmt:
	$(CARGO) fmt --all

# Figures as JSON lines: SAC updates/s and policy latency (more targets come with later work).
bench: release
	./target/release/dvnav bench env --json
	./target/release/dvnav bench transport --json
	./target/release/dvnav bench learner --batch 256 --json
	./target/release/dvnav bench learner --batch 128 --json

# Train with the default config: a learner plus 2 actors on this machine.
train: release
	./target/release/dvnav train --actors 2

clean:
	$(CARGO) clean
