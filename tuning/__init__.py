"""Identification of hysteresis models (cvxpy + Clarabel); PID tuning and validation."""
