"""Images in and out of the core: files and comparisons.

Modules
-------
image        EXR (OpenEXR) / PNG read & write, atomic writes
diff         image metrics (rmse, relmse, mae, max, psnr, flip), heatmaps

Imports only :mod:`links1.errors` (docs/architecture.md, "Packages").
"""
