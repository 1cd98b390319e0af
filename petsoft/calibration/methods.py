"""The names of the calibration methods a user may give (``--method``, ``method=``), without
importing PETSc (the command line lists them before PETSc is initialised)."""

#: The optimizers of :func:`petsoft.calibration.calibrate.run_calibration`.
METHODS = ("gauss-newton", "lbfgs", "gd", "newton", "brgn", "nelder-mead")
#: Other names a user may give a method (the spelled-out name of the short one).
METHOD_ALIASES = {"gradient-descent": "gd"}
