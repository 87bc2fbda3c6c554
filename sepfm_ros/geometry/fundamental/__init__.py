"""The fundamental-matrix problem every method solves: sampling and solving, scoring, refits,
Levenberg-Marquardt, inner sampling, degeneracy and plane checks, significance, input checks and
the final model (see docs/design.md, "Layout of the geometry")."""
