# restird — build, test, run, bench. `make help` lists the targets.
# Every target first makes sure the Debian packages are installed (scripts/install-deps.sh).

CC      ?= cc
SAN     ?= 0
BUILD   := build
# Sanitizer builds live in their own tree (build/san/) so the two kinds never mix.
TSAN    ?= 0
ifeq ($(SAN),1)
  OPT   := -O1 -g -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined
  OUT   := $(BUILD)/san
else ifeq ($(TSAN),1)
  # ThreadSanitizer (build/tsan/): the daemon and the threaded unit tests, run by test-tsan.
  OPT   := -O1 -g -fsanitize=thread -fno-omit-frame-pointer
  OUT   := $(BUILD)/tsan
else
  # Link-time optimisation lets the small per-file kernels (material, surface, lights, accel) be
  # inlined into the path loop across files; pt's loop asks for it with `flatten`
  # (reference_pt.c), since LTO's own size heuristics stopped doing it once the loop grew.
  OPT   := -O3 -g -fno-math-errno -flto=auto
  OUT   := $(BUILD)
endif
AR      := gcc-ar
OBJ     := $(OUT)/obj
CFLAGS  += -std=c17 -D_DEFAULT_SOURCE -Wall -Wextra -Wshadow -Wno-missing-field-initializers $(OPT) -MMD -MP -pthread
LDLIBS  := -lembree3 -lOpenEXRCore -ldeflate -lassimp -lcjson -lm -pthread
SERVER_LDLIBS := -lmicrohttpd
# Deferred ('='), so it is evaluated by the compile commands, after $(DEPS_OK) has installed
# pkg-config and OpenEXR on a fresh machine, not when the Makefile is read.
OPENEXR_CFLAGS = $(shell pkg-config --cflags OpenEXR 2>/dev/null)
PYTHON  := /usr/bin/python3
# DEPS=build: install only what building needs (the image's build stage); the stamp names the
# set, so a tree built that way still installs the test packages before its first test run.
DEPS    ?= all
DEPS_OK := $(BUILD)/.deps-ok$(if $(filter build,$(DEPS)),-build)

RENDERER_SRC := $(wildcard renderer/*/*.c)
RENDERER_OBJ := $(RENDERER_SRC:%.c=$(OBJ)/%.o)
PROTOCOL_SRC := $(wildcard protocol/*.c)
PROTOCOL_OBJ := $(PROTOCOL_SRC:%.c=$(OBJ)/%.o)
# The daemon's modules as a library (everything but the two programs' main files and the build's
# commit), so unit tests can link the registry and the HTTP-free parts of the server.
SERVER_SRC   := $(filter-out server/main.c server/cli.c server/version.c,$(wildcard server/*.c))
SERVER_OBJ   := $(SERVER_SRC:%.c=$(OBJ)/%.o)
UNIT_SRC     := $(wildcard tests/unit/test_*.c)
UNIT_BIN     := $(UNIT_SRC:tests/unit/%.c=$(OUT)/tests/%)
# The preview page (clients/web): its own files, and the npm packages it serves (uPlot) or is
# tested with (playwright-core), installed from the committed lockfile.
WEB          := clients/web
WEB_PAGE     := $(wildcard $(WEB)/page/*)
WEB_NPM      := $(WEB)/node_modules/.package-lock.json
WEB_VENDOR   := $(WEB)/node_modules/uplot/dist/uPlot.esm.js $(WEB)/node_modules/uplot/dist/uPlot.min.css

.PHONY: FORCE all deps test test-unit test-py test-perf test-cluster test-web test-fuzz test-tsan fuzz load run bench bench-report clean help
.SECONDARY:
all: $(OUT)/restir $(OUT)/restird

help:
	@echo "make            build build/restir (offline CLI) and build/restird (the daemon)"
	@echo "make test       unit, fuzz smoke, statistical, end-to-end, cluster and browser tests (SAN=1 for ASan/UBSan)"
	@echo "make test-cluster  the image and three daemons behind HAProxy (part of make test)"
	@echo "make test-perf  instructions per ray of pt under callgrind against tests/perf/instr_budget.json (part of make test)"
	@echo "make test-web   the preview page in headless chromium alone (screenshots: build/web-test/)"
	@echo "make test-tsan  the threaded unit tests and the daemon's concurrency tests under ThreadSanitizer"
	@echo "make run        start the daemon on 127.0.0.1:8080 (PORT=N: another port) with a default session on cornell-box;"
	@echo "                the preview page is at http://127.0.0.1:8080/"
	@echo "make bench      benchmarks (not tests): see docs/benchmarks.md"
	@echo "make bench-report  speed against accuracy, stability, Cycles: docs/report/ (QUICK=1: minutes)"
	@echo "make load       wrk and 10000-frame memory run against the daemon on loopback: see docs/reliability.md"
	@echo "make fuzz       run every libFuzzer target for FUZZ_SECONDS (default 60) each: see docs/reliability.md"
	@echo "make clean      remove everything make made"

deps: $(DEPS_OK)
$(DEPS_OK): scripts/install-deps.sh
	@bash scripts/install-deps.sh $(if $(filter build,$(DEPS)),--build)
	@mkdir -p $(BUILD) && touch $@

# Include paths follow the layers: renderer/ sees only itself, protocol/ sees the renderer,
# server/ sees both.
$(OBJ)/renderer/%.o: renderer/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(OPENEXR_CFLAGS) -Irenderer -c $< -o $@

$(OBJ)/protocol/%.o: protocol/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Irenderer -Iprotocol -c $< -o $@

$(OBJ)/server/%.o: server/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -Irenderer -Iprotocol -Iserver -c $< -o $@

# The commit the binaries are built from (server/version.h): COMMIT=abc1234 (on the command line
# or in the environment) where the tree is no git checkout, as in the image's build, which
# .dockerignore keeps .git out of (docker build --build-arg COMMIT=...); else HEAD. The stamp
# file holds it and is rewritten only when it changes, so a new commit recompiles
# server/version.c and relinks the two programs and test_api_jobs, the only ones that link it
# (not libserver.a, which every unit test links).
BUILD_COMMIT := $(or $(COMMIT),$(shell git rev-parse --short HEAD 2>/dev/null),unknown)
COMMIT_STAMP := $(OBJ)/commit-stamp
VERSION_OBJ  := $(OBJ)/server/version.o
FORCE:
$(COMMIT_STAMP): FORCE
	@mkdir -p $(dir $@)
	@echo '$(BUILD_COMMIT)' | cmp -s - $@ || echo '$(BUILD_COMMIT)' > $@

$(VERSION_OBJ): server/version.c $(COMMIT_STAMP) Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) -DRESTIRD_COMMIT='"$(BUILD_COMMIT)"' -Iserver -c $< -o $@

$(OBJ)/librenderer.a: $(RENDERER_OBJ)
	@rm -f $@
	$(AR) rcs $@ $^

$(OBJ)/libprotocol.a: $(PROTOCOL_OBJ)
	@rm -f $@
	$(AR) rcs $@ $^

$(OBJ)/libserver.a: $(SERVER_OBJ)
	@rm -f $@
	$(AR) rcs $@ $^

# The API description is linked into the daemon as bytes, so GET /v1/openapi.yaml cannot drift
# from the file in the tree.
$(OBJ)/openapi.o: protocol/openapi.yaml Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	ld -r -b binary -z noexecstack -o $@ $<

# npm ci is skipped while the installed tree matches the lockfile (npm writes its own record,
# node_modules/.package-lock.json; it is touched so it is newer than the lockfile).
$(WEB_NPM): $(WEB)/package.json $(WEB)/package-lock.json | $(DEPS_OK)
	cd $(WEB) && npm ci --no-audit --no-fund --loglevel=error
	@touch $@

# The page's files, uPlot included, are built into the daemon as a table (server/webui.h): the
# binary serves its own page with no directory to find at run time and nothing to traverse.
$(OBJ)/webui_files.c: $(WEB_PAGE) $(WEB_NPM) scripts/embed_web.py Makefile
	@mkdir -p $(dir $@)
	$(PYTHON) scripts/embed_web.py $@ $(WEB_PAGE) $(WEB_VENDOR)

$(OBJ)/webui_files.o: $(OBJ)/webui_files.c server/webui.h
	$(CC) $(CFLAGS) -Iserver -c $< -o $@

$(OUT)/restir: $(OBJ)/server/cli.o $(VERSION_OBJ) $(OBJ)/libserver.a $(OBJ)/libprotocol.a $(OBJ)/librenderer.a
	$(CC) $(CFLAGS) $^ $(LDLIBS) -o $@

$(OUT)/restird: $(OBJ)/server/main.o $(VERSION_OBJ) $(OBJ)/openapi.o $(OBJ)/webui_files.o $(OBJ)/libserver.a $(OBJ)/libprotocol.a $(OBJ)/librenderer.a
	$(CC) $(CFLAGS) $^ $(SERVER_LDLIBS) $(LDLIBS) -o $@

$(OUT)/tests/%: $(OBJ)/tests/unit/%.o $(OBJ)/libserver.a $(OBJ)/libprotocol.a $(OBJ)/librenderer.a
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $^ $(SERVER_LDLIBS) $(LDLIBS) -o $@

# test_api_jobs runs the API behind its HTTP front, which also serves the API description, the
# preview page and the build's commit (/metrics): it links them as the daemon does.
$(OUT)/tests/test_api_jobs: $(OBJ)/openapi.o $(OBJ)/webui_files.o $(VERSION_OBJ)

$(OBJ)/tests/unit/%.o: tests/unit/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(OPENEXR_CFLAGS) -Irenderer -Iprotocol -Iserver -Itests -c $< -o $@

# The fuzz smoke runs in the plain build only: its targets are built with their own sanitizers
# (build/fuzz/), so SAN=1 would repeat the same run.
ifeq ($(SAN),1)
test: test-unit test-py test-perf test-cluster test-web
else
test: test-unit test-fuzz test-py test-perf test-cluster test-web
endif

test-unit: $(UNIT_BIN)
	@fail=0; for t in $(UNIT_BIN); do echo "== $$t"; ./$$t || fail=1; done; exit $$fail

# The path tracer's instructions per ray under callgrind against tests/perf/instr_budget.json
# (about 15 s). Plain build only: a sanitizer build's counts measure the sanitizers.
ifeq ($(SAN),1)
test-perf:
	@echo "test-perf: skipped under SAN=1 (instruction counts of an instrumented build say nothing about the plain one)"
else ifeq ($(TSAN),1)
test-perf:
	@echo "test-perf: skipped under TSAN=1 (instruction counts of an instrumented build say nothing about the plain one)"
else
test-perf: $(OUT)/restir
	RESTIR_BIN=$(abspath $(OUT)/restir) bash tests/perf/instr_guard.sh
endif

# The sanitizer run leaves out the long statistical comparisons (tests/conftest.py, `statistical`):
# they test statistics, which the plain run does; the code they run is exercised under the
# sanitizers by smaller tests.
PYTEST_SELECT := $(if $(filter 1,$(SAN)),-m "not statistical")
test-py: $(OUT)/restir $(OUT)/restird
	RESTIR_BIN=$(abspath $(OUT)/restir) RESTIRD_BIN=$(abspath $(OUT)/restird) $(PYTHON) -m pytest -q -p no:cacheprovider --ignore=tests/cluster $(PYTEST_SELECT) tests

# The Dockerfile linter: dockerlinter from npm at the version docker/lint/package-lock.json pins,
# installed under build/ (never globally). --ignore-scripts: its install script downloads a
# ShellCheck binary; Debian's shellcheck (install-deps.sh) is used instead. It needs the
# machine's Node.js and npm (Node 20.11 or later: Debian's Node 18 cannot run it; it declares
# 22, but runs on 20); test_docker.py proves it judges by linting a faulty copy.
DOCKERLINT_DIR := $(BUILD)/dockerlint
DOCKERLINT     := $(DOCKERLINT_DIR)/node_modules/.bin/dockerlinter
$(DOCKERLINT): docker/lint/package.json docker/lint/package-lock.json | $(DEPS_OK)
	@command -v npm >/dev/null || { echo "make: the Dockerfile linter needs Node.js (20.11 or later) and npm" >&2; exit 1; }
	@mkdir -p $(DOCKERLINT_DIR)
	cp docker/lint/package.json docker/lint/package-lock.json $(DOCKERLINT_DIR)/
	cd $(DOCKERLINT_DIR) && npm ci --ignore-scripts --no-audit --no-fund --loglevel=error
	@touch $@

# No Docker engine needed: the Dockerfile is linted and its build commands run here, and three
# daemons run behind HAProxy (docker/haproxy.cfg) on loopback ports (tests/cluster/). The
# image's `make` runs inside the test: with everything it builds made first, it has nothing to
# do (SAN=1 builds in build/san/, so there it builds the plain tree, which no rule here touches).
test-cluster: $(OUT)/restir $(OUT)/restird $(DOCKERLINT)
	RESTIRD_BIN=$(abspath $(OUT)/restird) DOCKERLINT=$(abspath $(DOCKERLINT)) $(PYTHON) -m pytest -q -p no:cacheprovider tests/cluster

# The preview page in Debian's chromium, driven by playwright-core (node's test runner);
# screenshots and the daemon's log go to $(OUT)/web-test/.
test-web: $(OUT)/restird $(WEB_NPM)
	rm -rf $(OUT)/web-test
	RESTIRD_BIN=$(abspath $(OUT)/restird) WEB_TEST_OUT=$(abspath $(OUT)/web-test) PYTHON=$(PYTHON) \
		node --test --test-reporter=spec $(WEB)/test/

# ThreadSanitizer: the unit tests that start threads, then the pytest tests marked
# `concurrency` against a TSan daemon. Any report fails the run: the daemon exits with 66 on its
# first report (halt_on_error), which the tests see as a failed stop or a dead daemon.
TSAN_UNIT := test_parallel test_registry test_jobs test_api_jobs test_restir test_gbuffer test_restir_pt test_restir_sss \
             test_restir_sms test_restir_bdpt
TSAN_ENV  := TSAN_OPTIONS="halt_on_error=1 exitcode=66 second_deadlock_stack=1 suppressions=$(abspath tests/tsan.supp)"
ifeq ($(TSAN),1)
test-tsan: $(TSAN_UNIT:%=$(OUT)/tests/%) $(OUT)/restird
	@fail=0; for t in $(TSAN_UNIT); do echo "== tsan $$t"; $(TSAN_ENV) ./$(OUT)/tests/$$t || fail=1; done; exit $$fail
	$(TSAN_ENV) RESTIRD_BIN=$(abspath $(OUT)/restird) $(PYTHON) -m pytest -q -p no:cacheprovider -m concurrency tests
else
test-tsan:
	$(MAKE) TSAN=1 test-tsan
endif

# The daemon on 127.0.0.1:8080 (or PORT) with a ready session on the Cornell box; it prints the curl line
# that fetches a frame. Ctrl-C stops it cleanly.
PORT ?= 8080
run: $(OUT)/restird
	./$(OUT)/restird --listen 127.0.0.1:$(PORT) --default-session cornell-box

bench: $(OUT)/restir $(OUT)/restird $(OBJ)/librenderer.a
	bash bench/run.sh
	bash bench/instr_per_ray.sh | tee $(BUILD)/bench/instr.json
	$(PYTHON) bench/server_bench.py | tee $(BUILD)/bench/server.json
	$(PYTHON) bench/exr_delivery.py | tee $(BUILD)/bench/exr_delivery.md
	$(PYTHON) bench/restir_pt.py | tee $(BUILD)/bench/restir_pt.md
	$(PYTHON) bench/restir_sss.py | tee $(BUILD)/bench/restir_sss.md
	BENCH_SSS_MAX_DEPTH=1 $(PYTHON) bench/restir_sss.py | tee $(BUILD)/bench/restir_sss_depth1.md
	$(PYTHON) bench/bdpt.py | tee $(BUILD)/bench/bdpt.md
	QUICK=$(QUICK) $(PYTHON) bench/restir_bdpt.py | tee $(BUILD)/bench/restir_bdpt.md
	$(PYTHON) bench/sms.py | tee $(BUILD)/bench/sms.md

# The speed-against-accuracy report (docs/report/): every scene x method, stability, Cycles as a
# peer (Debian's blender, installed here unless REPORT_NO_CYCLES=1). QUICK=1 for a few minutes at
# 64x64.
bench-report: $(OUT)/restir $(OUT)/restird
	@[ "$(REPORT_NO_CYCLES)" = 1 ] || bash scripts/install-deps.sh blender
	QUICK=$(QUICK) $(PYTHON) bench/report.py

# ---- fuzzing: libFuzzer targets, built by clang with ASan + UBSan into build/fuzz/ ----
# Each target's seeds (and the inputs of every bug found, kept as regressions) are committed in
# tests/fuzz/<target>/; what a run discovers goes to build/fuzz/corpus/<target>/, first in the
# corpus list, so a run never writes into the tree. Crashing inputs land in build/fuzz/crashes/.
FUZZ_CC      := clang
FUZZ_OUT     := $(BUILD)/fuzz
FUZZ_OBJ     := $(FUZZ_OUT)/obj
FUZZ_CFLAGS  := -std=c17 -D_DEFAULT_SOURCE -Wall -Wextra -Wshadow -Wno-missing-field-initializers -O1 -g \
                -fno-omit-frame-pointer -fsanitize=address,undefined -fno-sanitize-recover=undefined -pthread
FUZZ_SECONDS ?= 60
FUZZ_SMOKE_SECONDS ?= 3
FUZZ_REQUESTS := session frame render reference
FUZZ_TARGETS := scene_json $(FUZZ_REQUESTS:%=request_%) mesh_ply mesh_obj exr
FUZZ_BIN     := $(FUZZ_TARGETS:%=$(FUZZ_OUT)/fuzz_%)
FUZZ_PARSER_session := 1
FUZZ_PARSER_frame := 2
FUZZ_PARSER_render := 3
FUZZ_PARSER_reference := 4
FUZZ_LIBS    := $(FUZZ_OBJ)/libprotocol.a $(FUZZ_OBJ)/librenderer.a
# The libraries get coverage instrumentation (fuzzer-no-link); only the targets link libFuzzer.
FUZZ_LIB_CFLAGS := $(FUZZ_CFLAGS) -fsanitize=fuzzer-no-link -MMD -MP

$(FUZZ_OBJ)/renderer/%.o: renderer/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(FUZZ_LIB_CFLAGS) $(OPENEXR_CFLAGS) -Irenderer -c $< -o $@

$(FUZZ_OBJ)/protocol/%.o: protocol/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(FUZZ_CC) $(FUZZ_LIB_CFLAGS) -Irenderer -Iprotocol -c $< -o $@

$(FUZZ_OBJ)/librenderer.a: $(RENDERER_SRC:%.c=$(FUZZ_OBJ)/%.o)
	@rm -f $@
	ar rcs $@ $^

$(FUZZ_OBJ)/libprotocol.a: $(PROTOCOL_SRC:%.c=$(FUZZ_OBJ)/%.o)
	@rm -f $@
	ar rcs $@ $^

FUZZ_LINK = $(FUZZ_CC) $(FUZZ_CFLAGS) -fsanitize=fuzzer -Irenderer -Iprotocol

$(FUZZ_OUT)/fuzz_scene_json: tests/fuzz/fuzz_scene_json.c $(FUZZ_LIBS)
	$(FUZZ_LINK) $^ $(LDLIBS) -o $@

$(FUZZ_OUT)/fuzz_request_%: tests/fuzz/fuzz_request.c $(FUZZ_LIBS)
	$(FUZZ_LINK) -DFUZZ_PARSER=$(FUZZ_PARSER_$*) $^ $(LDLIBS) -o $@

$(FUZZ_OUT)/fuzz_mesh_%: tests/fuzz/fuzz_mesh.c $(FUZZ_LIBS)
	$(FUZZ_LINK) '-DFUZZ_MESH_EXT="$*"' $^ $(LDLIBS) -o $@

$(FUZZ_OUT)/fuzz_exr: tests/fuzz/fuzz_exr.c $(FUZZ_LIBS)
	$(FUZZ_LINK) $(OPENEXR_CFLAGS) $^ $(LDLIBS) -o $@

# One target's run: replays its whole corpus, then mutates for $(1) seconds.
fuzz_run = mkdir -p $(FUZZ_OUT)/corpus/$(2) $(FUZZ_OUT)/crashes && \
	LSAN_OPTIONS=suppressions=$(abspath tests/fuzz/lsan.supp) ./$(FUZZ_OUT)/fuzz_$(2) -max_total_time=$(1) -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
	  -artifact_prefix=$(FUZZ_OUT)/crashes/$(2)- $(FUZZ_OUT)/corpus/$(2) tests/fuzz/$(2)

test-fuzz: $(FUZZ_BIN)
	@fail=0; for t in $(FUZZ_TARGETS); do echo "== fuzz smoke $$t ($(FUZZ_SMOKE_SECONDS) s)"; \
	  ( $(call fuzz_run,$(FUZZ_SMOKE_SECONDS),$$t) ) >$(FUZZ_OUT)/smoke-$$t.log 2>&1 \
	  && grep -h 'stat::number_of_executed_units' $(FUZZ_OUT)/smoke-$$t.log \
	  || { fail=1; tail -40 $(FUZZ_OUT)/smoke-$$t.log; }; done; exit $$fail

fuzz: $(FUZZ_BIN)
	@for t in $(FUZZ_TARGETS); do echo "== fuzz $$t ($(FUZZ_SECONDS) s, log $(FUZZ_OUT)/fuzz-$$t.log)"; \
	  ( $(call fuzz_run,$(FUZZ_SECONDS),$$t) ) >$(FUZZ_OUT)/fuzz-$$t.log 2>&1; rc=$$?; \
	  grep -hE '^(stat::number_of_executed_units|stat::new_units_added|SUMMARY|artifact_prefix|==[0-9]+==ERROR)' \
	    $(FUZZ_OUT)/fuzz-$$t.log; [ $$rc -eq 0 ] || exit 1; done

# The long load run (the short one is tests/test_load.py): loopback only, about a minute.
load: $(OUT)/restird
	mkdir -p $(BUILD)/load
	RESTIRD_BIN=$(abspath $(OUT)/restird) $(PYTHON) bench/load.py | tee $(BUILD)/load/load.json

clean:
	rm -rf $(BUILD) .pytest_cache tests/__pycache__ tests/cluster/__pycache__ clients/python/__pycache__ bench/__pycache__ \
	       $(WEB)/node_modules

-include $(wildcard $(FUZZ_OBJ)/*/*.d $(FUZZ_OBJ)/*/*/*.d)
-include $(RENDERER_OBJ:.o=.d) $(PROTOCOL_OBJ:.o=.d) $(SERVER_OBJ:.o=.d) $(OBJ)/server/cli.d $(OBJ)/server/main.d $(VERSION_OBJ:.o=.d) $(UNIT_SRC:tests/unit/%.c=$(OBJ)/tests/unit/%.d)
