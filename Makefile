# mlnseq: set-up, tests, benchmarks and the paper's reproduction.
.DEFAULT_GOAL := help
SHELL := /bin/bash

VENV := .venv
PY := $(VENV)/bin/python
MLNSEQ := $(VENV)/bin/mlnseq
SETUP_DONE := $(VENV)/.setup-done
PRACMLN_DONE := $(VENV)/.pracmln-done

.PHONY: help setup test test-slurm bench reproduce report clean dist docs-figures

help: ## List the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  %-12s %s\n", $$1, $$2}'

setup: $(SETUP_DONE) $(PRACMLN_DONE) ## Create .venv with mlnseq, its test dependencies and pracmln

# As root where apt-get is, set-up also installs Debian packages (ROS 1, slurm-wlm, munge) and says so first;
# NO_SYSTEM=1 leaves the system alone.
$(SETUP_DONE): pyproject.toml scripts/setup.sh scripts/link_ros1.py
	NO_SYSTEM=$(NO_SYSTEM) bash scripts/setup.sh

# pracmln (the paper's MLN engine) is optional: the tests compare against it, the reproduction does not use it.
$(PRACMLN_DONE): $(SETUP_DONE) scripts/install_pracmln.sh
	bash scripts/install_pracmln.sh $(VENV) && touch $@

# The suite's files go to TEST_WORKERS processes (pytest-xdist), a file's tests to one of them (its fixtures shared).
TEST_WORKERS ?= 2
test: setup ## Run the test suite in TEST_WORKERS processes (the SLURM cluster's test included: root, about a minute)
	$(VENV)/bin/pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

test-slurm: setup ## Run only the sweep through a real one-node SLURM cluster started on this machine (root)
	$(VENV)/bin/pytest -q -m slurm tests/stages/sweeps

dist: | $(SETUP_DONE) ## Build the wheel into dist/ (mlnseq is on no package index: install that file on a robot)
	rm -rf build && $(PY) -m pip wheel --no-deps --no-build-isolation --no-index -q -w dist .
	@ls dist/mlnseq-*.whl

docs-figures: setup ## Rerun the docs' commands and write what they print into the pages' quoted outputs and figures
	MLNSEQ_DOCS_FIGURES=write $(VENV)/bin/pytest -q -p no:cacheprovider tests/docs/test_docs_run.py tests/docs/test_docs_recordings.py \
	  "tests/cli/test_review_cli.py::test_a_click_shows_the_terms_explain_json_prints_for_that_frame"
	@git status --short README.md docs

bench: setup ## Run the benchmarks (figures and ratios measured side by side)
	$(PY) -m benchmarks


# --- the paper's reproduction ------------------------------------------------------------------------
# Size variables (a tiny run: make report SEEDS=0 EPOCHS=2 DESK_EPOCHS=2 FETCH_EPISODES=4 FRACTIONS=0.5).
# Epochs: Fetch's training accuracy levels off within 50 (the authors' count); DESK's still rises at 50,
# so it trains for train's default 100.
# Make does not see a changed variable: after changing one, `make clean` or choose another RUNS.
RUNS ?= runs
REPORTS ?= reports
SEEDS ?= 0 1 2 3 4
EPOCHS ?= 50
DESK_EPOCHS ?= 100
FETCH_EPISODES ?= 400
FRACTIONS ?= 0.01 0.02 0.05 0.1 0.25 0.5
FRACTION_SEEDS ?= $(SEEDS)
MODES ?= segment stream
TEMPORAL_MODES ?= $(MODES)
ABLATION_MODES ?= stream
JOBS ?= 2
FOLDS ?= 5
DESK_DIR ?= ../shared/data/desk-taurus
FETCH_SPEC ?= stages/specs/fetch.binarize.toml
FETCH_RICH_SPEC ?= examples/fetch-rich.binarize.toml
DESK_SPEC ?= stages/specs/desk.binarize.toml
FORMULAS_SPEC ?= stages/specs/paper.mln
TEMPORAL_SPEC ?= examples/temporal.mln
# steps of one FetchPickAndPlace-v4 episode (EPISODE_STEPS in stages/sources/fetch.py)
FETCH_EPISODE_FRAMES := 50

REPORT := $(REPORTS)/REPORT.md
STAGE = @bash scripts/timed_stage.sh $(RUNS) $(MLNSEQ)
DESK_FILES := $(DESK_DIR)/taurus_motion_train.txt $(DESK_DIR)/taurus_motion_test.txt
HAVE_DESK := $(if $(filter 2,$(words $(wildcard $(DESK_FILES)))),yes)

# Layout: one folder per dataset holding its frames, predicates, formulas and MLN weights, and below
# it one workdir per mode and seed (MODE/seed-N) whose models, predictions and metrics use those.
# Sequential logic (issue 12), per paper dataset D (fetch, desk), on D's frames and predicates (linked):
#   D-temporal      examples/temporal.mln (learned transitions, cll); its workdirs run D's LSTM of the same
#                   mode and seed (linked) and, in stream mode, a PriorLayer trained on its weights: the
#                   decoded rows
#   D-order         examples/D.order.mln (temporal.mln plus the order as hard rules); D's LSTM only
#   D-conjunctive   examples/conjunctive.mln (temporal.mln's transitions written as a conjunction); D's LSTM only
#   D-fixed-weight  D-temporal's weights and LSTM (linked), decoded with the network factor's weight 1
# D's own stream workdirs are decoded too (the paper's formulas: uniform transitions). The last three are
# the ablation, in ABLATION_MODES.
# Cross-validation (stream mode): D and its variants learn each of FOLDS folds' MLN weights beside their own
# (learn-weights --folds), and the stream networks are trained with FOLDS fold networks (train --folds):
# conflate learns the network factor's weight and scores every method on the out-of-fold predictions.
seed_dirs = $(foreach mode,$(2),$(foreach seed,$(3),$(RUNS)/$(1)/$(mode)/seed-$(seed)))
FRACTION_DATASETS := $(FRACTIONS:%=fetch-fraction-%)
SEQUENTIAL := fetch $(if $(HAVE_DESK),desk)
SEED_DIRS := $(call seed_dirs,fetch,$(MODES),$(SEEDS)) $(call seed_dirs,fetch-rich,segment,$(SEEDS)) \
  $(foreach d,$(FRACTION_DATASETS),$(call seed_dirs,$(d),segment,$(FRACTION_SEEDS))) \
  $(if $(HAVE_DESK),$(call seed_dirs,desk,$(MODES),$(SEEDS))) \
  $(foreach d,$(SEQUENTIAL),$(call seed_dirs,$(d)-temporal,$(TEMPORAL_MODES),$(SEEDS)) \
    $(call seed_dirs,$(d)-order,$(ABLATION_MODES),$(SEEDS)) $(call seed_dirs,$(d)-conjunctive,$(ABLATION_MODES),$(SEEDS)) \
    $(call seed_dirs,$(d)-fixed-weight,$(ABLATION_MODES),$(SEEDS)))
# The causal TCN (stages/networks/tcn.py) per paper dataset D, stream mode: D-tcn links D-temporal's frames,
# predicates, weights and fold weights (learned transitions), its lstm and priorlayer models are TCNs (--cell tcn)
# trained with FOLDS fold networks like the LSTM's, and it is decoded: a candidate of the cross-validated choice
# (issue 24). TCN_DATASETS= leaves it out.
TCN_DATASETS ?= $(SEQUENTIAL:%=%-tcn)
SEED_DIRS += $(foreach d,$(TCN_DATASETS),$(call seed_dirs,$(d),stream,$(SEEDS)))

# The stages run in processes forked from scripts/stage_server.py, which has imported torch and the data
# libraries once (`make report` alone runs each stage as a process of its own; the results are the same).
STAGE_SERVER := $(RUNS)/.stage-server.sock

reproduce: $(SETUP_DONE) ## Set up (without pracmln), then rebuild the paper's results into reports/REPORT.md
	@start=$$(date +%s); $(PY) scripts/stage_server.py serve $(STAGE_SERVER) & server=$$!; \
	  trap 'kill $$server 2>/dev/null' EXIT; \
	  for _ in $$(seq 50); do [ -S $(STAGE_SERVER) ] && break; sleep 0.1; done; \
	  MLNSEQ_STAGE_SERVER=$(STAGE_SERVER) $(MAKE) --no-print-directory -j$(JOBS) -Otarget report \
	  && echo "reproduce: $(REPORT) is up to date after $$(( $$(date +%s) - start )) s"

report: $(REPORT) ## Rebuild only the run's missing or outdated artifacts and the report (no set-up)
	@$(if $(HAVE_DESK),,echo "DESK Taurus files not found in $(DESK_DIR): the DESK half was skipped (set DESK_DIR=...)")

# Each stage's sources: its own file and every module of the library folders it imports, directly or through another
# folder (stages/ holds a file per stage and a folder per library), so a change anywhere a stage depends on reruns it.
# tests/stages/test_layout.py checks each list against the imports.
libraries = $(foreach folder,$(1),$(wildcard stages/$(folder)/*.py)) stages/__init__.py
NETWORK_LIBRARIES := catalog timeline mln networks model fusion choosing
COLLECT_SOURCES := stages/collect.py $(call libraries,catalog timeline sources labelling)
BINARIZE_SOURCES := stages/binarize.py $(call libraries,$(NETWORK_LIBRARIES) predicates learning)
FORMULAS_SOURCES := stages/formulas.py $(call libraries,catalog mln)
LEARN_SOURCES := stages/learn_weights.py $(call libraries,catalog timeline mln fusion choosing)
TRAIN_SOURCES := stages/train.py $(call libraries,$(NETWORK_LIBRARIES))
RECOGNIZER_SOURCES := stages/conflate.py $(call libraries,$(NETWORK_LIBRARIES))
EVAL_SOURCES := stages/eval.py $(call libraries,catalog timeline)
REPORT_SOURCES := stages/report.py mlnseq_cli/report.py $(call libraries,$(NETWORK_LIBRARIES) explaining reporting)

$(REPORT): $(SEED_DIRS:%=%/metrics.parquet) $(REPORT_SOURCES)
	$(STAGE) report --runs $(RUNS) --out $(REPORTS)

# Frames: Fetch simulated once with the paper's split (first 126 frames train), its episodes kept in
# FETCH_CACHE; every other Fetch dataset waits for it and reads the same episodes back; DESK imported.
FETCH_CACHE := $(RUNS)/cache
FETCH_COLLECT = $(STAGE) collect --env fetch --episodes $(FETCH_EPISODES) --cache $(FETCH_CACHE) --workdir $(@D)

$(RUNS)/fetch/frames.parquet: $(COLLECT_SOURCES)
	$(FETCH_COLLECT)

$(RUNS)/desk/frames.parquet: $(DESK_FILES) $(COLLECT_SOURCES)
	$(STAGE) collect --env desk --source $(DESK_DIR) --workdir $(@D)

# The richer predicate spec needs the goal: the same Fetch episodes with the 6 goal values added.
$(RUNS)/fetch-rich/frames.parquet: $(COLLECT_SOURCES) | $(RUNS)/fetch/frames.parquet
	$(FETCH_COLLECT) --goals

# Data efficiency: the same Fetch episodes, the first F of them train (the MLN learns on those only).
$(RUNS)/fetch-fraction-%/frames.parquet: $(COLLECT_SOURCES) | $(RUNS)/fetch/frames.parquet
	$(FETCH_COLLECT) --train-frames \
	  $$(awk 'BEGIN { n = int($* * $(FETCH_EPISODES) + 0.5); print (n < 1 ? 1 : n) * $(FETCH_EPISODE_FRAMES) }')

# A folder that uses another's files (FOLDER, SOURCE, NAMES): each a link, never recomputed.
define linked_files
$(foreach name,$(3),$(RUNS)/$(1)/$(name)): $(RUNS)/$(1)/%: $(RUNS)/$(2)/%
	@mkdir -p $$(@D) && ln -sfn ../$(2)/$$* $$@
endef
# Seed workdirs of FOLDER that run NETWORK of SOURCE's workdir of the same mode and seed (a link).
define linked_network
$(RUNS)/$(1)/%/models/$(3).pt: $(RUNS)/$(2)/%/models/$(3).pt | $(RUNS)/$(1)/%/.inputs-linked
	@mkdir -p $$(@D) && ln -sfn ../../../../$(2)/$$*/models/$(3).oof.parquet $$(@D)/$(3).oof.parquet \
	  && ln -sfn ../../../../$(2)/$$*/models/$(3).pt $$@
endef
$(foreach d,$(SEQUENTIAL),\
  $(eval $(call linked_files,$(d)-temporal,$(d),frames.parquet predicates.parquet)) \
  $(eval $(call linked_files,$(d)-order,$(d),frames.parquet predicates.parquet)) \
  $(eval $(call linked_files,$(d)-conjunctive,$(d),frames.parquet predicates.parquet)) \
  $(eval $(call linked_files,$(d)-fixed-weight,$(d)-temporal,frames.parquet predicates.parquet weights.parquet \
    weights.folds.parquet)) \
  $(eval $(call linked_network,$(d)-temporal,$(d),lstm)) $(eval $(call linked_network,$(d)-order,$(d),lstm)) \
  $(eval $(call linked_network,$(d)-conjunctive,$(d),lstm)) \
  $(eval $(call linked_network,$(d)-fixed-weight,$(d)-temporal,lstm)))
$(foreach d,$(TCN_DATASETS),$(eval $(call linked_files,$(d),$(d:%-tcn=%)-temporal,frames.parquet predicates.parquet \
  weights.parquet weights.folds.parquet)))

.SECONDEXPANSION:
.SECONDARY:  # keep every artifact the chain makes
spec_of = $(if $(filter fetch-rich,$(1)),$(FETCH_RICH_SPEC),$(if $(filter desk,$(1)),$(DESK_SPEC),$(FETCH_SPEC)))
formulas_of = $(if $(filter %-temporal,$(1)),$(TEMPORAL_SPEC),$(if $(filter %-order,$(1)),examples/$(1:%-order=%).order.mln,\
  $(if $(filter %-conjunctive,$(1)),examples/conjunctive.mln,$(FORMULAS_SPEC))))
# The dataset folders whose stream workdirs cross-validate: each fold's MLN weights are learned too.
FOLDED := $(foreach d,$(SEQUENTIAL),$(d) $(d)-temporal $(d)-order $(d)-conjunctive)

$(RUNS)/%/predicates.parquet: $(RUNS)/%/frames.parquet $$(call spec_of,$$*) $(BINARIZE_SOURCES)
	$(STAGE) binarize --spec $(call spec_of,$*) --workdir $(@D)

$(RUNS)/%/formulas.mln: $(RUNS)/%/predicates.parquet $$(call formulas_of,$$*) $(FORMULAS_SOURCES)
	$(STAGE) formulas --spec $(call formulas_of,$*) --workdir $(@D)

# pll for the paper's per-frame formulas, cll (exact conditional likelihood) where a formula uses Next.
$(RUNS)/%/weights.parquet: $(RUNS)/%/formulas.mln $(LEARN_SOURCES)
	$(STAGE) $(strip learn-weights $< $(if $(filter $(FOLDED),$*),--folds $(FOLDS)) --workdir $(@D))

$(RUNS)/%/weights.folds.parquet: $(RUNS)/%/weights.parquet
	@test -e $@ || { echo "$@ missing: $* learns no fold weights (FOLDED in the Makefile)"; false; }

# A seed workdir DATASET/MODE/seed-N links its dataset's frames, predicates and weights (and fold weights). In
# stream mode the networks train on the whole training split and FOLDS fold networks beside them (--folds):
# conflate learns the decoded methods' network factor weight on their out-of-fold predictions and scores every
# method there, which chooses the method to deploy. Segment mode keeps the paper's protocol (last epoch, no folds).
part_of = $(word $(1),$(subst /, ,$(2)))
stem_word = $(call part_of,$(1),$*)
dataset_dir = $(RUNS)/$(call stem_word,1)
mode_of = $(call stem_word,2)
# The networks a workdir of DATASET and MODE runs in conflate. PriorLayer is trained again on D-temporal's weights in
# stream mode only; D-temporal in segment mode, D-order and D-fixed-weight run the LSTM alone (the ablation's methods).
networks_in = lstm $(if $(filter %-temporal,$(1)),$(if $(filter stream,$(2)),priorlayer),\
  $(if $(filter %-order %-conjunctive %-fixed-weight,$(1)),,priorlayer))
networks_of = $(call networks_in,$(call stem_word,1),$(mode_of))
# Decoded: the sequential folders, and the paper datasets' stream workdirs (their ablation row).
decoded = $(filter $(SEQUENTIAL:%=%-temporal) $(SEQUENTIAL:%=%-order) $(SEQUENTIAL:%=%-conjunctive) $(SEQUENTIAL:%=%-fixed-weight) \
  $(if $(filter stream,$(mode_of)),$(SEQUENTIAL) $(TCN_DATASETS)),$(call stem_word,1))
conflate_flags = $(if $(decoded),--decode all) $(if $(filter %-fixed-weight,$(call stem_word,1)),--network-weight 1)

$(RUNS)/%/.inputs-linked:
	@mkdir -p $(@D) && for name in frames predicates weights weights.folds; do ln -sfn ../../$$name.parquet $(@D)/$$name.parquet; done
	@touch $@

# Training: one run per dataset, mode and network trains every seed's network side by side (train --seed A --workdir
# .../seed-A --seed B ...: each ends where it would alone, up to rounding; 5 LSTMs 1.4-1.9x as fast as one after
# another). The folders whose LSTM is another's (linked_network above) train only their PriorLayer.
# The runs the report draws per-epoch curves of (Fig. 7, 8, Table III's best epoch: the paper datasets' segment mode)
# measure every epoch; every other run measures its last (train --measure).
CURVES := fetch desk
LINKED_LSTM := $(foreach d,$(SEQUENTIAL),$(d)-temporal $(d)-order $(d)-conjunctive $(d)-fixed-weight)
DATASET_MODES := $(sort $(foreach dir,$(SEED_DIRS),$(patsubst $(RUNS)/%/,%,$(dir $(dir)))))
trained_networks = $(filter-out $(if $(filter $(LINKED_LSTM),$(1)),lstm),$(call networks_in,$(1),$(2)))
train_flags = --mode $(2) --epochs $(if $(filter desk desk-%,$(1)),$(DESK_EPOCHS),$(EPOCHS)) \
  $(if $(filter %-tcn,$(1)),--cell tcn) $(if $(filter stream,$(2)),--folds $(FOLDS),--folds 0) \
  $(if $(and $(filter $(CURVES),$(1)),$(filter segment,$(2))),--measure every-epoch)
# In stream mode, PriorLayer's fold networks read each fold's MLN weights (a D-tcn folder links D-temporal's).
train_inputs = $(RUNS)/$(1)/frames.parquet $(TRAIN_SOURCES) $(if $(filter priorlayer,$(3)),$(RUNS)/$(1)/predicates.parquet \
  $(RUNS)/$(1)/weights.parquet $(if $(and $(filter stream,$(2)),$(filter $(FOLDED) $(TCN_DATASETS),$(1))),\
  $(RUNS)/$(1)/weights.folds.parquet))
define trained_side_by_side
$(addsuffix /models/$(3).pt,$(4)) &: $(call train_inputs,$(1),$(2),$(3)) | $(addsuffix /.inputs-linked,$(4))
	$$(STAGE) $(strip train --method $(3) $(call train_flags,$(1),$(2)) \
	  $(foreach dir,$(4),--seed $(patsubst $(RUNS)/$(1)/$(2)/seed-%,%,$(dir)) --workdir $(dir)))
endef
$(foreach dm,$(DATASET_MODES),$(foreach n,$(call trained_networks,$(call part_of,1,$(dm)),$(call part_of,2,$(dm))),\
  $(eval $(call trained_side_by_side,$(call part_of,1,$(dm)),$(call part_of,2,$(dm)),$(n),\
    $(filter $(RUNS)/$(dm)/seed-%,$(SEED_DIRS))))))

$(RUNS)/%/predictions.parquet: $$(foreach n,$$(networks_of),$(RUNS)/%/models/$$(n).pt) \
  $$(foreach name,frames predicates weights,$$(dataset_dir)/$$(name).parquet) $(RECOGNIZER_SOURCES) \
  $$(if $$(filter $(FOLDED) $(SEQUENTIAL:%=%-fixed-weight),$$(call stem_word,1)),$$(dataset_dir)/weights.folds.parquet)
	$(STAGE) $(strip conflate $(conflate_flags) --workdir $(@D))

$(RUNS)/%/metrics.parquet: $(RUNS)/%/predictions.parquet $(EVAL_SOURCES)
	$(STAGE) eval --method all --no-tables --workdir $(@D)

clean: ## Remove generated workdirs and reports (keeps .venv)
	rm -rf $(RUNS) $(REPORTS) mlnseq-work
