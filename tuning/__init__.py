"""Identification of hysteresis models (cvxpy + Clarabel, ``identify``), the feedforward (``feedforward``), the
paper's rig calibrated (``calibrate``), PID tuning with CasADi (``pid``), gains compared (``compare``), Monte Carlo
validation (``validate``) and the verdict on a gain set (``verdict``)."""
