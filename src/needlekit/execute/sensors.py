"""The registered tip sensors (:data:`needlekit.execute.plugins.SENSORS`): the simulated EM
sensor on the tip, and a tracker's TRANSFORMs over OpenIGTLink. Whichever runs, every
sample passes the sensor guard (:class:`~needlekit.execute.guard.SensorGuard`)."""

from __future__ import annotations

from dataclasses import asdict

from needlekit.control.em import EMSensor
from needlekit.errors import InvalidInputError
from needlekit.execute.igtl_link import IGTLTipSensor

__all__ = ["em_sensor", "igtl_sensor"]


def em_sensor(setup) -> EMSensor:
    """The ``em`` sensor: :class:`~needlekit.control.em.EMSensor` with the run's
    ``settings.sensor`` (40 Hz, 0.4 mm and 0.5 deg SD, 5 ms latency by default).

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    EMSensor
    """
    return EMSensor(setup.settings.sensor, setup.rng)


def igtl_sensor(setup) -> IGTLTipSensor:
    """The ``igtl`` sensor: the tip from a tracker's TRANSFORMs named ``setup.tip_name``
    arriving over ``setup.link`` (``needlekit execute --igtl ... --tip-from-igtl NAME``).

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    IGTLTipSensor

    Raises
    ------
    InvalidInputError
        No link or no transform name in the setup.
    """
    if setup.link is None or not setup.tip_name:
        raise InvalidInputError(
            "--sensor", "igtl reads a tracker over a live link: give --igtl and --tip-from-igtl"
        )
    return IGTLTipSensor(setup.link, setup.tip_name)


em_sensor.parameters = lambda settings: asdict(settings.sensor)
igtl_sensor.parameters = lambda settings: {"rate_hz": settings.sensor.rate_hz}
