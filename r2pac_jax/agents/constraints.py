"""Constraint pieces the OSRL-ported baselines share (CPQ, BCQ-Lag): the per-step cost budget
of a Q_c threshold and OSRL's PID Lagrangian controller, as pure functions."""
from __future__ import annotations

import jax
import jax.numpy as jnp


def q_threshold(cost_limit, discount: float, episode_len: int):
    """OSRL's Q_c threshold cost_limit (1 - g^L) / ((1 - g) L): an episode's cost budget spread
    evenly over its L steps, discounted (CPQ's q_thres, BCQ-L's qc_thres)."""
    return cost_limit * (1.0 - discount**episode_len) / (1.0 - discount) / episode_len


def pid_multiplier(qc: jax.Array, thres, error_old, error_integral, kp, ki, kd):
    """OSRL's LagrangianPIDController.control: qc [B] -> (multiplier [], error_old [],
    error_integral []), the controller's state after the call.

    e = mean(qc - thres); integral = relu(integral + e); derivative = relu(e - e_old);
    multiplier = relu(kp relu(e) + ki integral + kd derivative)."""
    e = jnp.mean(qc - thres)
    diff = jax.nn.relu(e - error_old)
    integral = jax.nn.relu(error_integral + e)
    mult = jax.nn.relu(kp * jax.nn.relu(e) + ki * integral + kd * diff)
    return mult, e, integral
