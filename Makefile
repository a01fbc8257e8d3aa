# ubake: the two README commands (make demo, make test) and the rest.
BUILD ?= build
JOBS ?= 2
SANITIZE_CTEST_ARGS ?=
LEVEL ?= ../shared/levels/real/oa_dm4/oa_dm4.gltf
SHARED_LEVELS := $(firstword $(wildcard ../shared/levels/real) $(wildcard shared/levels/real))

.PHONY: all deps build demo test test-sanitize bench fuzz clean

all: build

deps:
	@bash scripts/install-deps.sh

# After deps even under make -j (cmake run before the packages are in fails); a failed
# configure leaves no cache behind, so the next make configures again.
$(BUILD)/CMakeCache.txt: | deps
	cmake -S . -B $(BUILD) -DCMAKE_BUILD_TYPE=RelWithDebInfo >/dev/null || \
	  { rm -f $(BUILD)/CMakeCache.txt; exit 1; }

build: deps $(BUILD)/CMakeCache.txt
	cmake --build $(BUILD) -j $(JOBS)

DEMO_CAMERA ?= -2,-6.8,-17.5,-2,-7.6,-4,70
demo: build
	@mkdir -p out/demo
	$(BUILD)/ubake bake $(LEVEL) -o out/demo --quality fast
	@name=$$(basename $(LEVEL) | sed 's/\.[^.]*$$//'); \
	  $(BUILD)/ubake render out/demo/$$name.ubk --camera $(DEMO_CAMERA) --size 960x540 \
	    -o out/demo/$${name}_render.png && \
	  $(BUILD)/ubake info out/demo/$$name.ubk
	@echo "demo: outputs in out/demo/ (.ubk, EXR lightmaps, PNG previews, a rendered view, report.json)"
	@ls -l out/demo

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

test-sanitize: deps
	cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=Debug -DUB_SANITIZE=ON >/dev/null
	cmake --build build-asan -j $(JOBS)
	@# Any ASan/UBSan report fails its test (-fno-sanitize-recover=all, halt_on_error).
	@# The whole suite, slow label included (what CI runs). Built at -O1 (CMakeLists.txt), the
	@# tests' OpenMP waits passive: 70 tests in 388-480 s on this 2-core machine (2026-12-05;
	@# 873 s at -O0 with spinning waits), ~9 min with the build.
	@# SANITIZE_CTEST_ARGS="-LE slow" leaves the slow ones out for a quicker local run.
	cd build-asan && ASAN_OPTIONS=detect_leaks=1:halt_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 ctest --output-on-failure -j $(JOBS) --timeout 1800 $(SANITIZE_CTEST_ARGS)

bench: build
	@for b in $(BUILD)/bench_*; do echo "== $$b"; UB_BUILD=$(BUILD) $$b || exit 1; done
	@echo "== bench_bake on the shipped real levels"
	UB_BUILD=$(BUILD) $(BUILD)/bench_bake $(SHARED_LEVELS)/oa_dm4/oa_dm4.gltf $(SHARED_LEVELS)/q3dm6ish/q3dm6ish.gltf

FUZZ_SECONDS ?= 60
FUZZ_TARGETS ?= fuzz_gltf fuzz_ubk fuzz_ubk_crc
FUZZ_NICE ?= nice -n 10
# The whole library is compiled with coverage (fuzzer-no-link) so libFuzzer is guided by
# the loaders' code, not only by the target file; UBSan aborts so the fuzzer sees it.
FUZZ_FLAGS := -fsanitize=fuzzer-no-link,address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer
fuzz: deps
	CC=clang CXX=clang++ cmake -S . -B build-fuzz -DCMAKE_BUILD_TYPE=RelWithDebInfo -DUB_FUZZ=ON \
	  "-DCMAKE_C_FLAGS=$(FUZZ_FLAGS)" "-DCMAKE_CXX_FLAGS=$(FUZZ_FLAGS)" \
	  "-DCMAKE_EXE_LINKER_FLAGS=-fsanitize=address,undefined" >/dev/null
	cmake --build build-fuzz -j $(JOBS) --target $(FUZZ_TARGETS)
	@for n in $(FUZZ_TARGETS); do mkdir -p build-fuzz/corpus-$$n build-fuzz/artifacts-$$n; \
	  echo "== $$n for $(FUZZ_SECONDS) s"; \
	  dict=; [ -f tests/fuzz/$$n.dict ] && dict=-dict=tests/fuzz/$$n.dict; \
	  $(FUZZ_NICE) build-fuzz/$$n -max_total_time=$(FUZZ_SECONDS) -print_final_stats=1 $$dict \
	    -artifact_prefix=build-fuzz/artifacts-$$n/ build-fuzz/corpus-$$n tests/fuzz/corpus-$$n \
	    || { echo "fuzz: $$n found a crash: see build-fuzz/artifacts-$$n/"; exit 1; }; done

clean:
	rm -rf $(BUILD) build-asan build-fuzz

# Accuracy vs time (README "Accuracy vs time"): `ubake sweep` on every shipped level into
# out/sweep/<level>/ (sweep.csv, sweep.png, reference_points.csv). The real levels take
# hours on 2 cores; SWEEP_LEVELS picks a subset, SWEEP_ARGS adds options (e.g.
# SWEEP_ARGS="--ladder quick").
SWEEP_ARGS ?=
SWEEP_LEVELS ?= $(BUILD)/levels/cornell.gltf $(BUILD)/levels/sunroom.gltf \
  $(wildcard $(SHARED_LEVELS)/oa_dm4/oa_dm4.gltf $(SHARED_LEVELS)/q3dm6ish/q3dm6ish.gltf \
             $(SHARED_LEVELS)/kaos/kaos.gltf)
.PHONY: sweep sweep-presets
sweep: build
	@for l in $(SWEEP_LEVELS); do n=$$(basename $$l .gltf); echo "== sweep $$l -> out/sweep/$$n"; \
	  $(BUILD)/ubake sweep $$l -o out/sweep/$$n $(SWEEP_ARGS) || exit 1; done
	@$(sweep_join_presets)
	@echo "sweep: out/sweep/<level>/sweep.csv and sweep.png; out/sweep/presets.md"

# README "The presets, measured": the three presets only (`--ladder presets`), each level with
# the options below (cornell, sunroom and oa_dm4 took ~70 min at load average 6-22 on the
# shared 2-core machine, most of it oa_dm4's converged bake; q3dm6ish takes ~20 min and kaos
# ~75 min on a quiet machine (its converged bake ~52 min);
# SWEEP_PRESET_ARGS_<level> overrides one level, SWEEP_ARGS adds to all), then the
# levels' DIR/presets.md joined into out/sweep/presets.md (one table, the commit on top):
# paste that into README. Run it under nice on a shared machine: nice -n 10 make sweep-presets
SWEEP_PRESET_ARGS_cornell ?= --points 64 --ref-spp 65536 --converged-rays 4096
SWEEP_PRESET_ARGS_sunroom ?= --points 64 --ref-spp 65536 --converged-rays 4096
SWEEP_PRESET_ARGS_oa_dm4 ?= --points 128 --ref-spp 65536 --converged-rays 2048
SWEEP_PRESET_ARGS_q3dm6ish ?= --points 64 --ref-spp 32768 --converged-rays 2048
SWEEP_PRESET_ARGS_kaos ?= --points 64 --ref-spp 32768 --converged-rays 2048
sweep-presets: build
	@$(foreach l,$(SWEEP_LEVELS),echo "== sweep presets $(l) -> out/sweep/$(basename $(notdir $(l)))" && \
	  $(BUILD)/ubake sweep $(l) -o out/sweep/$(basename $(notdir $(l))) --ladder presets \
	    $(SWEEP_PRESET_ARGS_$(basename $(notdir $(l)))) $(SWEEP_ARGS) &&) true
	@$(sweep_join_presets)
# Only the joining (after levels were swept one at a time).
.PHONY: sweep-table
sweep-table:
	@$(sweep_join_presets)

# out/sweep/presets.md from the levels' presets.md, in SWEEP_LEVELS order: the table header
# once, every level's rows, then every level's line saying how it was measured.
define sweep_join_presets
f=; for l in $(SWEEP_LEVELS); do p=out/sweep/$$(basename $$l .gltf)/presets.md; [ -f $$p ] && f="$$f $$p"; done; \
if [ -n "$$f" ]; then { echo "Commit $$(git rev-parse --short HEAD)$$(git diff --quiet HEAD -- . 2>/dev/null || echo ' + uncommitted changes'), $$(date -u +'%Y-%m-%d %H:%M UTC'), $$(nproc) cores ($$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo | head -1)), load average now $$(cut -d' ' -f1-3 /proc/loadavg)."; echo; \
  awk 'FNR <= 2 && NR != FNR { next } /^\|/' $$f; echo; awk '!/^\|/ && NF { print "- " $$0 }' $$f; } > out/sweep/presets.md; \
  echo "sweep: out/sweep/presets.md (the README table)"; fi
endef

# The ESTATE-scale level (levels/README.md "estate"), not made by the build (big): writes
# out/estate/estate.gltf (not in $(BUILD)/levels, whose levels the tests bake) and prints
# its plan (receivers, passes, estimates) without baking. ESTATE_ARGS adds generator parameters (e.g. ESTATE_ARGS="--param scale=0.2").
# The benchmark: $(BUILD)/bench_estate (reduced scale, extrapolated; --full for all of it).
ESTATE_ARGS ?=
.PHONY: estate
estate: build
	$(BUILD)/ubake-genlevel estate -o out/estate $(ESTATE_ARGS)
	$(BUILD)/ubake bake out/estate/estate.gltf -o out/estate/bake --quality draft --plan-only --no-progress
