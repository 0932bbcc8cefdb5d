"""Monocular 3D reconstruction: the KCS algorithm (Algorithm 1), the refinement, the pipeline."""
