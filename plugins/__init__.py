"""mitsvbrdf_plugins: the project's Mitsuba 3 plugins written in Python.

The scene files in ``scenes/`` name three plugin types: the ``lcd`` emitter, the ``svbrdf_ggx``
BSDF and the ``importance`` integrator. Their implementations and registration are added with the
Mitsuba plugin work (issue 3); until then the torch reference renderer reads the same scene files
through :class:`mitsvbrdf.Rig` and renders without Mitsuba.
"""
