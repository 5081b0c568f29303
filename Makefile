# links1: the two commands are `make demo` and `make test`; both run `make setup` first.
# `make test-fast` is the quick loop while working: the tests not marked slow (pyproject.toml).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.links1-installed
LLVM19 := /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1

.PHONY: setup demo test test-fast bench clean llvm

setup: $(STAMP) llvm

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[test]'
	touch $(STAMP)

# drjit 1.5 needs libLLVM >= 16 (Debian 12's libLLVM 15 aborts); see ../shared/docs/platform-notes.md
llvm:
	@if [ -e $(LLVM19) ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "links1 setup: installing libllvm19 (needed by drjit 1.5's LLVM backend)"; \
	  (apt-get install -y -qq libllvm19 >/dev/null 2>&1 || (apt-get update -qq && apt-get install -y -qq libllvm19 >/dev/null)) || \
	  { echo "links1 setup: could not install libllvm19; install it with: apt-get install libllvm19" >&2; exit 1; }; \
	else echo "links1 setup: libLLVM 19 is missing; install it (as root): apt-get install libllvm19" >&2; exit 1; fi

demo: setup
	mkdir -p out
	$(BIN)/links1 render scenes/fig11.xml --renderer core -o out/demo.png
	@echo "demo image: $(CURDIR)/out/demo.png"

# the suite on TEST_JOBS processes (pytest-xdist), a test file to a process (its module fixtures
# and compiled kernels shared); TEST_JOBS=0 runs it in this process
TEST_JOBS ?= 2
test: setup
	$(BIN)/python -m pytest -q -p no:cacheprovider -n $(TEST_JOBS) --dist loadfile tests

test-fast: setup
	$(BIN)/python -m pytest -q -p no:cacheprovider -m "not slow" tests

bench: setup
	$(BIN)/python -m compare.bench --quick

clean:
	rm -rf out .pytest_cache
