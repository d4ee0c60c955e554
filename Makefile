# lidar_sim_ros developer commands. `make demo` and `make test` work on a bare
# Python 3.11 machine: they build .venv from the requirements files first.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= demo-output

.PHONY: venv demo demo-offline demo-gnc demo-loop test bench bench-node bench-gnc bench-compare bench-big-mesh bench-campaign constraints clean

venv: $(STAMP)

# constraints.txt pins the versions that were tested (make constraints rewrites it);
# the warm-up compiles the numba kernels once, so no node compiles at its first start.
$(STAMP): requirements.txt requirements-ros.txt requirements-dev.txt requirements-gnc.txt requirements-campaign.txt requirements-loop.txt constraints.txt setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints.txt -r requirements.txt -r requirements-ros.txt -r requirements-dev.txt -r requirements-gnc.txt -r requirements-campaign.txt -r requirements-loop.txt
	$(BIN)/pip install --quiet --no-deps -e .
	$(BIN)/python -m lidar_sim_ros.warm_up
	touch $(STAMP)

## The main job: pose player + node over real DDS, recorded to a rosbag2, figures rendered.
demo: $(STAMP)
	$(BIN)/python -m lidar_sim_ros.demo --out $(OUT)

## Offline path: the core pipeline straight to a rosbag2 and figures, no DDS.
demo-offline: $(STAMP)
	$(BIN)/lidar-sim simulate config/scenario.yaml --frames 10 --out $(OUT)/offline

## Navigation in the loop: player + simulator + two pose trackers over DDS -> gnc.json + figure.
demo-gnc: $(STAMP)
	$(BIN)/python -m lidar_sim_ros.gnc.demo --out $(OUT)/gnc

## The closed GNC loop over DDS on Basilisk (extra [loop]), truth cloud and full error model
## -> loop.json + loop.png (docs/loop.md). About 2.5 min simulated per cloud.
demo-loop: $(STAMP)
	$(BIN)/python -m lidar_sim_ros.loop.demo --out $(OUT)/loop

# Two parts: the tests that start nodes or a cluster of their own (marker serial, see
# test/conftest.py) alone, the rest first on TEST_WORKERS pytest-xdist workers. Both
# parts always run; the target fails if either failed. Each part prints its slowest
# tests (--durations), so a CI log shows where the time budget goes.
# One BLAS thread per test process: the workers already fill the cores, and OpenBLAS's
# own threads on the fits' small matrices spin against the other worker (a 52 x 52
# pinv took 14 ms with them on a loaded 2-core machine, 0.5 ms without; the two
# pointing_few_c compares 73 -> 46 s of CPU).
# Bytecode cached (a machine exporting PYTHONDONTWRITEBYTECODE=1 otherwise recompiles the
# package and re-rewrites every test module's asserts in each worker, node and CLI process).
TEST_WORKERS ?= 2
test: $(STAMP)
	export OPENBLAS_NUM_THREADS=1; unset PYTHONDONTWRITEBYTECODE; status=0; \
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadscope --durations=20 -m 'not serial' test || status=1; \
	$(BIN)/python -m pytest -q --durations=10 -m serial test || status=1; \
	exit $$status

bench: $(STAMP)
	$(BIN)/python bench/bench_pipeline.py --out bench.json

## `make bench-node SCENARIO=config/scenario_all_effects.yaml` runs the node with that scenario;
## CEPTON_UDP=1 runs it without and with the Cepton UDP output and reports packets/s and ratios.
bench-node: $(STAMP)
	$(BIN)/python bench/bench_node.py --out bench_node.json $(if $(SCENARIO),--scenario $(SCENARIO)) $(if $(PUBLISH_LATENCY),--publish-latency $(PUBLISH_LATENCY)) $(if $(CEPTON_UDP),--cepton-udp)

## What each LiDAR error costs the pose tracker, and its time per frame (offline).
bench-gnc: $(STAMP)
	$(BIN)/python bench/bench_tracker.py --out bench_tracker.json

## lidar-sim compare on a 12-frame and a one-minute recording: seconds per stage, peak RSS;
## then what the separation plan of a tie adds (two foreign ties, with and without --no-plan).
bench-compare: $(STAMP)
	$(BIN)/python bench/bench_compare.py --out bench_compare.json --data bench_compare_data
	$(BIN)/python bench/bench_compare_plan.py --out bench_compare_plan.json --data bench_compare_plan_data

## lidar-sim compare with a 2-million-triangle mesh (BIG_MESH_SEGMENTS=850): its peak RSS (issue 22).
BIG_MESH_SEGMENTS ?= 850
bench-big-mesh: $(STAMP)
	$(BIN)/python bench/bench_big_mesh.py --segments $(BIG_MESH_SEGMENTS) --out bench_big_mesh.json --data bench_big_mesh_data

## Rewrite constraints.txt from the venv: the versions just tested (the package itself left out).
constraints: $(STAMP)
	{ echo '# Tested versions, used by make venv (pip install -c). Regenerate: make constraints'; \
	  $(BIN)/pip freeze --exclude-editable | grep -iv '^lidar[-_]sim[-_]ros'; } > constraints.txt
	touch $(STAMP)

## Campaign engine: frames/s on 1 and 2 Dask workers, speedup, overhead per run; then the
## client's peak RSS at 1,000 and 100,000 one-frame runs (CAMPAIGN_SCALE_RUNS to change).
CAMPAIGN_SCALE_RUNS ?= 1000 100000
bench-campaign: $(STAMP)
	$(BIN)/python bench/bench_campaign.py --out bench_campaign.json
	$(BIN)/python bench/bench_campaign_scale.py --runs $(CAMPAIGN_SCALE_RUNS) --out bench_campaign_scale.json

clean:
	rm -rf $(VENV) $(OUT) build install log *.egg-info bench.json bench_node.json bench_tracker.json bench_compare.json bench_compare_data bench_compare_plan.json bench_compare_plan_data bench_big_mesh.json bench_big_mesh_data bench_campaign.json bench_campaign_scale.json
