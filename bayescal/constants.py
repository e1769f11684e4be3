"""Numerical constants shared by the summaries, the reports and the figures.

Imports nothing from bayescal (it sits at the bottom of the import graph).
"""

from __future__ import annotations

__all__ = ["Z90", "CHI2_2_95", "CHI2_3_95"]

#: standard normal 95th percentile: half-width of a central 90 % interval, in sd
Z90 = 1.6448536269514722
#: chi-square quantile with 2 degrees of freedom at 0.95: a 2-D ellipse holding 95 %
CHI2_2_95 = 5.991464547107979
#: chi-square quantile with 3 degrees of freedom at 0.95: a 3-D ellipsoid holding 95 %
CHI2_3_95 = 7.814727903251179
