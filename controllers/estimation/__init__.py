"""Estimation: the target estimator (the paper's UKF, the manoeuvring-ship CT-UKF, their IMM), when it starts
and restarts (estimation), and a turning ship seen through a constant-velocity filter (course_turn)."""
