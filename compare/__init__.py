"""Benchmarks of links1 (not tests): ``python -m compare.bench``, ``compare.blob_study``,
``compare.skip_study``, ``compare.scaling``. Results (JSON, markdown, PNG) go to
``compare/results/``; see docs/benchmarks.md."""
