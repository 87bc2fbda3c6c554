"""Pipeline layer: images -> features -> matches -> estimate (shared by the node and offline tools)."""
