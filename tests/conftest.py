"""Loaded by pytest before any test directory's conftest."""
# CPython 3.11.7's ast.parse can raise "SystemError: AST constructor recursion depth mismatch"
# when other threads run during it (python/cpython#106905, pytest-dev/pytest#10763). Without
# this import, hypothesis's pytest plugin first imports hypothesis (so pytest parses and
# rewrites it) in its terminal summary, while the Dask tests' threads are winding down: seen
# once in 20 runs of tests/dist alone, after every test had passed. Imported here, it is
# parsed before any test starts a thread.
import hypothesis.internal.observability  # noqa: F401

import os
import signal

import pytest

# A shell without job control starts background commands with SIGINT ignored, and an ignored
# signal stays ignored across exec: the CLI processes that the Ctrl-C tests start would then never
# see their SIGINT (Python installs its KeyboardInterrupt handler only over the default action).
# The tests stand for a user at a terminal, where Ctrl-C has its default action.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

#: what ``make test-fast`` (``-m "not slow"`` over tests/) must keep at least one test of: the
#: core, the Mitsuba plugin, partitioning, the docs checks, the stress tests (the CLI's own tests
#: are in core/ and dist/)
FAST_LOOP_DIRS = ("core", "plugins", "dist", "docs", "stress")


@pytest.hookimpl(trylast=True)  # after -m has deselected
def pytest_collection_modifyitems(config, items):
    """``make test-fast`` stops at collection when marking tests slow left a directory of
    FAST_LOOP_DIRS without a test."""
    here = os.path.dirname(os.path.abspath(__file__))
    whole = [os.path.abspath(a) for a in config.args] == [here]
    if not whole or config.option.markexpr != "not slow" or config.option.keyword:
        return
    seen = {os.path.relpath(str(item.path), here).split(os.sep)[0] for item in items}
    empty = [d for d in FAST_LOOP_DIRS if d not in seen]
    if empty:
        raise pytest.UsageError(f"-m 'not slow' selects no test in tests/{', tests/'.join(empty)}: "
                                "the fast loop must keep at least one test of each")
