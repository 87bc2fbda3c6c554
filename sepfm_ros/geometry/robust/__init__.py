"""The generic robust loop, nothing specific to F: trial counts F(k, r), samplers (uniform,
PROSAC), SPRT, the LMedS scale, the contract a problem implements (``contract.Problem``), the
stopping rule, the race of arms and the loop (``loop.run_ransac``)."""
