"""Synthetic recordings with exact ground truth, built from real BVH clips (design.md,
"Evaluation protocol")."""
