# lidar_sim_ros developer commands. `make demo` and `make test` work on a bare
# Python 3.11 machine: they build .venv from the requirements files first.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= demo-output

.PHONY: venv demo demo-offline test bench bench-node bench-campaign clean

venv: $(STAMP)

$(STAMP): requirements.txt requirements-ros.txt requirements-dev.txt requirements-campaign.txt setup.py
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -r requirements.txt -r requirements-ros.txt -r requirements-dev.txt
	$(BIN)/pip install --quiet -r requirements-campaign.txt
	$(BIN)/pip install --quiet --no-deps -e .
	touch $(STAMP)

## The main job: pose player + node over real DDS, recorded to a rosbag2, figures rendered.
demo: $(STAMP)
	$(BIN)/python -m lidar_sim_ros.demo --out $(OUT)

## Offline path: the core pipeline straight to a rosbag2 and figures, no DDS.
demo-offline: $(STAMP)
	$(BIN)/lidar-sim simulate config/scenario.yaml --frames 10 --out $(OUT)/offline

test: $(STAMP)
	$(BIN)/python -m pytest -q test

bench: $(STAMP)
	$(BIN)/python bench/bench_pipeline.py --out bench.json

bench-node: $(STAMP)
	$(BIN)/python bench/bench_node.py --out bench_node.json

## Campaign engine: frames/s on 1 and 2 Dask workers, speedup, overhead per run.
bench-campaign: $(STAMP)
	$(BIN)/python bench/bench_campaign.py --out bench_campaign.json

clean:
	rm -rf $(VENV) $(OUT) build install log *.egg-info bench.json bench_node.json bench_campaign.json
