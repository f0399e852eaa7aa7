"""Perception in the planner: range readings (shared.scans) fused into a map of the world,
turned into a signed distance field that cost terms and the guide read."""
