"""The evaluation behind ``msx compare``: speed against accuracy.

- ``driver``: ``msx compare`` itself — the stages, in order, each writing into the report folder.
- ``renders``: the comparison scenes, their converged Smith reference (cached),
  spp sweeps over every model × estimator, error against time, bias² and
  variance, object masks, side-by-side images and difference images.
- ``atlas``: per model, furnace error, noise per call, raw non-finite values,
  largest contribution and time per call over roughness × incidence.
- ``lobes``: f·cos θ_o in the plane of incidence per scattering order.
- ``energy``: directional albedo against roughness.
- ``report``: the HTML page, the CSV files and the "which model" section.

Every number in the report is computed by the run that writes it.
"""
