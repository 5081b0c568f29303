"""The front ends of links1: they choose and drive a renderer, and may name the plugin.

Modules
-------
renderers      the Renderer protocol, make_renderer("core" | "mitsuba", ...), Mitsuba's errors in one line
cli_options    the options ``links1 render`` and ``links1 schedule`` share
cli            ``links1 render | diff | schedule`` (the console script ``links1``)
pytest_plugin  golden-image fixture for users' test suites (pytest entry point ``links1``)

No core module imports these (docs/architecture.md, "Dependencies"); :mod:`links1.partition`
is a front end too.
"""
