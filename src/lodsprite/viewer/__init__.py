"""The interactive viewer: a window that drives lodsprite's techniques (lodsprite view)."""
