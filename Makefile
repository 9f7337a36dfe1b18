# restird — build, test, run, bench. `make help` lists the targets.
# Every target first makes sure the Debian packages are installed (scripts/install-deps.sh).

CC      ?= cc
SAN     ?= 0
BUILD   := build
# Sanitizer builds live in their own tree (build/san/) so the two kinds never mix.
ifeq ($(SAN),1)
  OPT   := -O1 -g -fsanitize=address,undefined -fno-omit-frame-pointer -fno-sanitize-recover=undefined
  OUT   := $(BUILD)/san
else
  # Link-time optimisation inlines the small per-file kernels (material, surface, lights) into
  # the path loop: 7 % fewer instructions per ray on the Cornell box (callgrind).
  OPT   := -O2 -g -fno-math-errno -flto=auto
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
DEPS_OK := $(BUILD)/.deps-ok

RENDERER_SRC := $(wildcard renderer/*.c)
RENDERER_OBJ := $(RENDERER_SRC:%.c=$(OBJ)/%.o)
PROTOCOL_SRC := $(wildcard protocol/*.c)
PROTOCOL_OBJ := $(PROTOCOL_SRC:%.c=$(OBJ)/%.o)
# The daemon's modules as a library (everything but the two programs' main files), so unit
# tests can link the registry and the HTTP-free parts of the server.
SERVER_SRC   := $(filter-out server/main.c server/cli.c,$(wildcard server/*.c))
SERVER_OBJ   := $(SERVER_SRC:%.c=$(OBJ)/%.o)
UNIT_SRC     := $(wildcard tests/unit/test_*.c)
UNIT_BIN     := $(UNIT_SRC:tests/unit/%.c=$(OUT)/tests/%)
# The preview page (clients/web): its own files, and the npm packages it serves (uPlot) or is
# tested with (playwright-core), installed from the committed lockfile.
WEB          := clients/web
WEB_PAGE     := $(wildcard $(WEB)/page/*)
WEB_NPM      := $(WEB)/node_modules/.package-lock.json
WEB_VENDOR   := $(WEB)/node_modules/uplot/dist/uPlot.esm.js $(WEB)/node_modules/uplot/dist/uPlot.min.css

.PHONY: all deps test test-unit test-py test-cluster test-web run bench clean help
.SECONDARY:
all: $(OUT)/restir $(OUT)/restird

help:
	@echo "make            build build/restir (offline CLI) and build/restird (the daemon)"
	@echo "make test       unit, statistical, end-to-end, cluster and browser tests (SAN=1 for ASan/UBSan)"
	@echo "make test-cluster  the image and three daemons behind HAProxy (part of make test)"
	@echo "make test-web   the preview page in headless chromium alone (screenshots: build/web-test/)"
	@echo "make run        start the daemon on 127.0.0.1:8080 with a default session on cornell-box;"
	@echo "                the preview page is at http://127.0.0.1:8080/"
	@echo "make bench      benchmarks (not tests): see docs/benchmarks.md"
	@echo "make clean      remove everything make made"

deps: $(DEPS_OK)
$(DEPS_OK): scripts/install-deps.sh
	@bash scripts/install-deps.sh
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

$(OUT)/restir: $(OBJ)/server/cli.o $(OBJ)/libserver.a $(OBJ)/libprotocol.a $(OBJ)/librenderer.a
	$(CC) $(CFLAGS) $^ $(LDLIBS) -o $@

$(OUT)/restird: $(OBJ)/server/main.o $(OBJ)/openapi.o $(OBJ)/webui_files.o $(OBJ)/libserver.a $(OBJ)/libprotocol.a $(OBJ)/librenderer.a
	$(CC) $(CFLAGS) $^ $(SERVER_LDLIBS) $(LDLIBS) -o $@

$(OUT)/tests/%: $(OBJ)/tests/unit/%.o $(OBJ)/libserver.a $(OBJ)/libprotocol.a $(OBJ)/librenderer.a
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $^ $(SERVER_LDLIBS) $(LDLIBS) -o $@

$(OBJ)/tests/unit/%.o: tests/unit/%.c Makefile | $(DEPS_OK)
	@mkdir -p $(dir $@)
	$(CC) $(CFLAGS) $(OPENEXR_CFLAGS) -Irenderer -Iprotocol -Iserver -Itests -c $< -o $@

test: test-unit test-py test-cluster test-web

test-unit: $(UNIT_BIN)
	@fail=0; for t in $(UNIT_BIN); do echo "== $$t"; ./$$t || fail=1; done; exit $$fail

test-py: $(OUT)/restir $(OUT)/restird
	RESTIR_BIN=$(abspath $(OUT)/restir) RESTIRD_BIN=$(abspath $(OUT)/restird) $(PYTHON) -m pytest -q -p no:cacheprovider --ignore=tests/cluster tests

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
	RESTIRD_BIN=$(abspath $(OUT)/restird) WEB_TEST_OUT=$(abspath $(OUT)/web-test) PYTHON=$(PYTHON) \
		node --test --test-reporter=spec $(WEB)/test/

# The daemon on 127.0.0.1:8080 with a ready session on the Cornell box; it prints the curl line
# that fetches a frame. Ctrl-C stops it cleanly.
run: $(OUT)/restird
	./$(OUT)/restird --listen 127.0.0.1:8080 --default-session cornell-box

bench: $(OUT)/restir $(OUT)/restird $(OBJ)/librenderer.a
	bash bench/run.sh
	bash bench/instr_per_ray.sh | tee $(BUILD)/bench/instr.json
	$(PYTHON) bench/server_bench.py | tee $(BUILD)/bench/server.json
	$(PYTHON) bench/restir_pt.py | tee $(BUILD)/bench/restir_pt.md

clean:
	rm -rf $(BUILD) .pytest_cache tests/__pycache__ tests/cluster/__pycache__ clients/python/__pycache__ bench/__pycache__ \
	       $(WEB)/node_modules

-include $(RENDERER_OBJ:.o=.d) $(PROTOCOL_OBJ:.o=.d) $(SERVER_OBJ:.o=.d) $(OBJ)/server/cli.d $(OBJ)/server/main.d $(UNIT_SRC:tests/unit/%.c=$(OBJ)/tests/unit/%.d)
