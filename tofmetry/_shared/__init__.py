"""Helpers that several packages of tofmetry need, kept once (the scikit-image ``_shared`` idea).

Not public API: import the modules themselves (``from tofmetry._shared.geometry import ...``).
Everything here depends only on numpy, matplotlib and the standard library, never on another
tofmetry package, so that every layer may use it.

* :mod:`.atomic` — atomic file and folder writing (temporary sibling, then rename)
* :mod:`.figures` — a matplotlib figure to a PNG file, atomically
* :mod:`.geometry` — rotation angle of a pose, SVD plane fit, principal axes
* :mod:`.study_constants` — the reference study's figures that the code uses, with names
"""
