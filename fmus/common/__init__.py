"""Shared model library of every FlexFusion FMU: parameters, kinematics, dynamics, noise, FMI base."""
