"""Kinematics: DH forward kinematics, rotations, closed-form inverse kinematics, paths."""
