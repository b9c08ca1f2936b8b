"""Parallel kinematic machines: hexapod and tripod models, identification, tracker pose measurement."""
