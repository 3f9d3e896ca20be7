"""Studies: the paper's reproductions (``jko-cvx reproduce``), the solver studies (``jko-cvx study``),
solver comparisons and parameter sweeps."""
