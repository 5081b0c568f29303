"""The camera and its film's reconstruction filter.

Modules
-------
camera       Mitsuba perspective / orthographic sensors: film point -> ray
filters      Mitsuba's reconstruction filters and the gather that applies them (shared with the plugin)

Imports only :mod:`links1.maths` (docs/architecture.md, "Packages").
"""
