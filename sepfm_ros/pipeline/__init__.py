"""Pipeline layer: images -> features -> matches -> estimate (shared by node and offline tools)."""
