# The two commands of the README:
#   make demo   set up .venv and run the demo scene (3D dam break, ~49k particles, to t = 0.4 s, 2 peer processes + viewer) into runs/demo
#   make test   set up .venv and run the default test suite (two worker processes; WORKERS=N)
# Others:
#   make check         the fast tier for edits (pytest -m fast, under 3 minutes on 2 cores once numba's cache
#                      is warm): scene validation, kernels and neighbours, conservation, 1 process vs 2 peers
#                      bitwise, hostile messages, the wire format, CLI errors; a subset of make test
#   make test-slow     the heavier suites (pytest -m slow)
#   make test-gpu      on a machine with a GPU: CPU/CUDA parity, a 200-step run, the GPU benchmark, launch
#                      costs, 300 M particles stepping, two peers on one GPU (runs/gpu/log.txt; ~9 min)
#   make bench         sph bench (add the reference codes with: bash scripts/setup_bench.sh; make bench-external)

PY := .venv/bin/python
SPH := .venv/bin/sph

.PHONY: setup demo test check test-slow test-gpu bench bench-external

setup:
	bash scripts/setup.sh

demo: setup
	$(SPH) run configs/dam_break.toml --peers 2 --until 0.4 --set render.every=50 --set decomposition.balance_every=100 --out runs/demo

# make test runs the suite in WORKERS processes (pytest-xdist), a test file to a process so that a
# module's fixtures (the CUDA parity run, the PTX compile) run once: numba compiles on one core, and
# the cold suite is mostly compiling. WORKERS=auto takes every core; WORKERS=0 runs in this process.
WORKERS ?= 2

test: setup
	$(PY) -m pytest -n $(WORKERS) --dist loadfile

check: setup
	$(PY) -m pytest -m fast

test-slow: setup
	$(PY) -m pytest -m slow

test-gpu: setup
	bash scripts/gpu_check.sh runs/gpu

bench: setup
	$(SPH) bench --json runs/bench/bench.json

bench-external: setup
	$(SPH) bench --sizes 50000 --external --steps 200 --json runs/bench/bench_external.json
