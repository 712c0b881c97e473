"""Figures of the reference study (Lachat et al. 2015) that the code uses, with names.

Section numbers are the study's. Each value is used where the study's own figure is the default
or the point of comparison; a measured value replaces it wherever one is available.
"""

from __future__ import annotations

import math

#: §3.3.1, Fig. 4: a black target returns about 1/6 of the amplitude of a white one (2000 vs 12000)
BLACK_AMPLITUDE_RATIO = 6.0

#: §3.3.1: and reads about 12 mm longer [mm]
BLACK_BIAS_MM = 12.0

#: slope k of the amplitude bias ``k ln(A_white / A)`` [mm per unit ln] implied by the two figures
#: above: 12 / ln 6 = 6.70 mm
AMPLITUDE_BIAS_MM_PER_LN = BLACK_BIAS_MM / math.log(BLACK_AMPLITUDE_RATIO)
