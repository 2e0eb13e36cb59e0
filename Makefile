# panovocc — two commands for a new user: `make demo` and `make test`.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEB_PKGS := libgl1 libegl1 libusb-1.0-0 libgomp1 libosmesa6
DEMO := work/demo
export PYOPENGL_PLATFORM ?= osmesa

.PHONY: setup demo test test-quick bench bench-jitter bench-render bench-scale bench-shards reproduce-tables clean help

help:
	@echo "make demo   set up .venv, then render -> map -> eval on the embedded default scene"
	@echo "make test   set up .venv, then run the whole test suite"
	@echo "make test-quick  the suite without the end-to-end runs marked slow (pytest -m 'not slow')"
	@echo "make bench  mapper speed against Open3D TSDF fusion on the same frames"
	@echo "make bench-render  render speed against bare Open3D ray casting on the same rays"
	@echo "make bench-shards  map frames/s on 1 and 2 Dask workers (one thread each), the bytes a shard sends back"
	@echo "make bench-jitter  occupancy IoU against per-frame pose jitter, clean and realistic depth, spill thinning and face resolution off/on"
	@echo "make bench-scale  the long-term memory at building scale: RAM, disk, time per frame early and late, revise"
	@echo "make pan-holo  the embedded Pan-Holo split: a house, realistic depth, 300 frames, lifted ground truth"
	@echo "make gt-protocol  lifted ground truth and the mapper against mesh truth (4 seeds, clean and realistic depth)"
	@echo "make reproduce-tables [SMALL=1]  the whole benchmark (tables, figures) into results/ (SMALL: results/small/)"

# Debian libraries (open3d: libgl1 libegl1 libusb-1.0-0 libgomp1; headless pyrender: libosmesa6),
# installed only when missing and only when running as root.
setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	@missing=""; for p in $(DEB_PKGS); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ]; then echo "installing Debian packages:$$missing"; \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null) \
	      || { echo "apt-get failed for:$$missing" >&2; exit 1; }; \
	  else echo "warning: missing Debian packages:$$missing (run as root or install them)" >&2; fi; \
	fi
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --disable-pip-version-check --upgrade pip 2>/dev/null || true
	set -o pipefail; $(BIN)/python -m pip install -q --disable-pip-version-check -e '.[test,clip,viz,ros]' 2>&1 | { grep -v "^WARNING: Location" || true; }
	# pyrender pins PyOpenGL 3.1.0, whose OSMesa bindings are broken: take a fixed release after it.
	set -o pipefail; $(BIN)/python -m pip install -q --disable-pip-version-check 'PyOpenGL>=3.1.7' 2>&1 | { grep -v -e "^WARNING: Location" -e "pyrender" -e "dependency resolver" || true; }
	touch $(STAMP)

demo: setup
	$(BIN)/panovocc demo --overwrite $(DEMO)

test: setup
	$(BIN)/python -m pytest -q -p no:cacheprovider tests

test-quick: setup
	$(BIN)/python -m pytest -q -p no:cacheprovider -m "not slow" tests

bench: setup
	$(BIN)/panovocc bench work/bench

# The long-term memory at building scale (docs/mapping.md, "Scale"): synth --building, render at 512x256,
# map, revise 1,000 frames; one table in work/bench-scale/scale.{md,csv,json}. SCALE_ARGS: e.g. --scene house.
bench-scale: setup
	$(BIN)/python -m panovocc_cli.benchmark.scale work/bench-scale $(SCALE_ARGS)

# Pose jitter (issue 22; docs/slam.md "Pose jitter"): homes 2-4, 60 frames at 512x256, clean and realistic depth,
# jitter 0 / 5 mm 0.05 deg / 10 mm 0.1 deg / 20 mm 0.2 deg, each map exported with the spill thinning and the face
# resolution off and on;
# work/bench-jitter/jitter.{csv,md}, every step kept and reused. JITTER_ARGS: e.g. --seeds 0 --house.
bench-jitter: setup
	$(BIN)/python -m panovocc_cli.benchmark.jitter work/bench-jitter $(JITTER_ARGS)

# map --workers (docs/sharding.md): frames/s on 1 and 2 local Dask workers, one thread each, same frames
bench-shards: setup
	NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m panovocc_cli.benchmark.shardbench work/bench-shards

bench-render: setup
	$(BIN)/panovocc synth work/bench-scene --seed 0
	$(BIN)/python -m panovocc_cli.rendering.bench work/bench-scene --width 1024 --frames 60

# The benchmark (docs/benchmark.md): a local Dask cluster of two workers; finished tasks cached in
# work/benchmark-cache, so an interrupted run resumes. SMALL=1: a few minutes, into results/small/.
REPRO_OUT = $(if $(SMALL),results/small,results)
reproduce-tables: setup
	$(BIN)/panovocc reproduce $(if $(SMALL),--small) --out $(REPRO_OUT) --cache work/benchmark-cache --overwrite

clean:
	rm -rf work $(VENV) *.egg-info

# The embedded Pan-Holo split (docs/gt.md): a house-scale home rendered with realistic depth noise along a
# long trajectory, its ground truth lifted from every 10th frame's labels (the real benchmark's protocol).
PANHOLO := work/pan-holo
PANHOLO_SEED ?= 0
.PHONY: pan-holo gt-protocol
pan-holo: setup
	$(BIN)/panovocc synth --house --seed $(PANHOLO_SEED) --overwrite $(PANHOLO)/scene
	$(BIN)/panovocc render $(PANHOLO)/scene $(PANHOLO)/seq --width 1024 --noise realistic --seed $(PANHOLO_SEED) --overwrite
	$(BIN)/panovocc gt --from-sequence $(PANHOLO)/seq $(PANHOLO)/gt.npz --annotated every:10 --overwrite
	$(BIN)/panovocc gt $(PANHOLO)/scene $(PANHOLO)/gt_mesh.npz --overwrite

# The lifted ground truth measured against mesh truth (README "Pan-Holo360D", docs/gt.md).
gt-protocol: setup
	$(BIN)/python scripts/gt_protocol.py work/gt-protocol --seeds 0 1 2 3 --width 512
