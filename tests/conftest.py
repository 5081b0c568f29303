"""Loaded by pytest before any test directory's conftest."""
# CPython 3.11.7's ast.parse can raise "SystemError: AST constructor recursion depth mismatch"
# when other threads run during it (python/cpython#106905, pytest-dev/pytest#10763). Without
# this import, hypothesis's pytest plugin first imports hypothesis (so pytest parses and
# rewrites it) in its terminal summary, while the Dask tests' threads are winding down: seen
# once in 20 runs of tests/dist alone, after every test had passed. Imported here, it is
# parsed before any test starts a thread.
import hypothesis.internal.observability  # noqa: F401
