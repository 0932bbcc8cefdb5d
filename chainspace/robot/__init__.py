"""Robots: joint angles fitted with Pinocchio and their validation."""
