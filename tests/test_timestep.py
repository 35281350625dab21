"""The rate a filter integrates over a step (``estimators.timestep``), and which series hold means over their steps."""
from __future__ import annotations

import numpy as np
import pytest

from mavattitude import quaternion as quat
from mavattitude.estimators import create
from mavattitude.flight import means_over_steps


def gyro_only(rate_over_step: bool):
    """mahony with no correction at all (kp = ki = 0, the reading as it is): the gyro integrated."""
    t = np.arange(0.0, 2.0, 0.02)
    gyro = np.column_stack([np.sin(3 * t), 0.5 * t, np.cos(2 * t)])  # a rate that changes every step
    f = create("mahony", kp=0.0, ki=0.0, strict=True)
    f.rate_over_step = rate_over_step
    f.initialize(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3))
    return t, gyro, f.update(t, gyro, np.tile([0.0, 0.0, -9.8], (len(t), 1)), None)


@pytest.mark.parametrize("rate_over_step", [False, True])
def test_samples_of_the_rate_take_the_trapezoid_means_over_a_step_the_sample_alone(rate_over_step):
    t, gyro, q = gyro_only(rate_over_step)
    expected = [np.array([1.0, 0.0, 0.0, 0.0])]
    for i in range(1, len(t)):
        rate = gyro[i] if rate_over_step else 0.5 * (gyro[i] + gyro[i - 1])
        expected.append(quat.integrate_gyro(expected[-1], rate, t[i] - t[i - 1]))
    np.testing.assert_allclose(q, np.array(expected), rtol=0, atol=1e-12)


def test_only_delta_angles_are_means_over_the_logged_step():
    assert means_over_steps("IMT[0]") and means_over_steps("vehicle_imu[1]")
    # ArduPilot's IMU and MAVLink's samples of the filtered rate; PX4's sensor_combined averages
    # over the sensor's period, not over a slower log's step
    assert not any(means_over_steps(k) for k in ("IMU[0]", "RAW_IMU", "HIGHRES_IMU", "sensor_combined", "GYR[0]"))
