"""The paper's separable method: line pairs (Sec. 4), stage 1's H_e and stage 2's arms with three
fixed line points (Sec. 5), line planes, periodic line pairs and the two-stage method."""
