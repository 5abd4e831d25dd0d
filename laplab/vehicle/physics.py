"""Which car a model drives: DeepRacer's physics generations, chosen as deepracer-simapp chooses them.

simapp reads ``model_metadata.json``'s ``"version"`` (a number; simapp's launch files and
``markov/constants.py``):

===========================  ==================================  ======================
``version``                  DeepRacer's car                      laplab's car
===========================  ==================================  ======================
below 5 (1-4)                effort-controlled wheels (simapp 4)  ``deepracer-v4``
5 up to 6                    kinematics controllers (simapp 5)    ``deepracer-v5``
6 and above                  simapp 6 on ROS 2 (DeepRacer on AWS) ``deepracer-v6``
missing                      what DeepRacer on AWS writes: 6      ``deepracer-v6``
===========================  ==================================  ======================

Versions 1 and 2 drove other cars (simapp's ``mit`` and ``confetti`` models) in DeepRacer's first months;
laplab gives them the oldest DeepRacer car it has measured, v4 (3 and 4 share its URDF).
``laplab train --physics V`` (V = 4, 5, 6 or ``classic``) overrides the version; ``classic`` is laplab's
car before these generations (``laplab-classic``), which model folders trained before them keep.
"""

from __future__ import annotations

from laplab.errors import UserError
from laplab.vehicle.params import CLASSIC, DEEPRACER_V4, DEEPRACER_V5, DEEPRACER_V6, PRESETS

DEFAULT_VERSION = "6"  # what DeepRacer on AWS writes into a new model's model_metadata.json
PHYSICS_CHOICES = {"4": DEEPRACER_V4.name, "5": DEEPRACER_V5.name, "6": DEEPRACER_V6.name, "classic": CLASSIC.name}
CAR_VERSIONS = {DEEPRACER_V4.name: "4", DEEPRACER_V5.name: "5", DEEPRACER_V6.name: "6"}


class PhysicsError(UserError, ValueError):
    """A physics version or car name that laplab does not know (names the value and the choices)."""

    default_field = "physics"


def car_for_version(version: str | float | None) -> str:
    """The car (a preset name) DeepRacer drives for a ``model_metadata.json`` ``version``."""
    if version is None or str(version).strip() == "":
        version = DEFAULT_VERSION
    try:
        number = float(str(version).strip())
    except ValueError:
        raise PhysicsError(f"model_metadata.json \"version\" {version!r} is not a number: DeepRacer's versions are "
                           f"1-6 (below 5: the effort-controlled car; 5; 6: DeepRacer on AWS's)") from None
    if number != number or number <= 0:
        raise PhysicsError(f"model_metadata.json \"version\" {version!r} must be a positive number (1-6)")
    if number < 5:
        return DEEPRACER_V4.name
    if number < 6:
        return DEEPRACER_V5.name
    return DEEPRACER_V6.name


def resolve_physics(choice: str, option: str = "--physics") -> str:
    """``--physics`` (4, 5, 6, ``classic`` or a car's name) -> the car's preset name; ``option`` is what
    an error calls the choice (the console's API field is ``physics``)."""
    text = str(choice).strip()
    if text in PRESETS:
        return text
    key = text.lower()
    if key in PHYSICS_CHOICES:
        return PHYSICS_CHOICES[key]
    try:
        return car_for_version(text)
    except PhysicsError:
        raise PhysicsError(f"{option} {choice!r}: write 4, 5 or 6 (DeepRacer's physics version: 4 the "
                           f"effort-controlled car, 5 the console's from 2023, 6 DeepRacer on AWS's) or classic "
                           f"(laplab's car before them)") from None


def version_for_car(car: str, current: str) -> str:
    """The ``model_metadata.json`` version that makes DeepRacer drive ``car`` (``current`` when it
    already does, or for laplab's classic car, which DeepRacer has not)."""
    wanted = CAR_VERSIONS.get(car)
    if wanted is None:
        return current
    try:
        if car_for_version(current) == car:
            return current
    except PhysicsError:
        pass
    return wanted


def car_of_config(config: dict) -> str:
    """The car of a model folder's ``laplab.json`` (a dict as stored): its ``vehicle``; in folders written
    before DeepRacer's cars (config version 1, ``"deepracer"``), laplab's classic car, which they trained on;
    with none, the car of its metadata's version."""
    vehicle = config.get("vehicle")
    if int(config.get("version", 1) or 1) < 2 and vehicle in (None, "deepracer"):
        return CLASSIC.name
    if vehicle:
        return str(vehicle)
    metadata = config.get("model_metadata")
    return car_for_version(metadata.get("version") if isinstance(metadata, dict) else None)


def describe_car(car: str) -> str:
    """One line on a car for people: its name and what it is."""
    preset = PRESETS.get(car)
    return f"{car} ({preset.description})" if preset is not None and preset.description else car
