"""Shared library of every FlexFusion FMU: parameters, frames and gravity, the arm's dynamics and
kinematics, noise, sample times, the Kalman toolkit, and the FMI bases (FlexFusionSlave, and
FilterAdapter for estimators). See ARCHITECTURE.md."""
