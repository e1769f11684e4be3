"""Statistics that results, fitters and samplers share: the identifiability
report and covariance transforms between the 7 identifiable and the 8 paper
parameters, and the autocorrelation time / effective sample size of a chain.

See ``docs/architecture.md`` for the layers and what each may import.
"""
