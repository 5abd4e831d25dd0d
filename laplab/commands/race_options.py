"""The race-type options of ``laplab train`` (and the race command): ``--race-type`` and its settings."""

from __future__ import annotations

import argparse

from laplab.sim.race_type import (
    RACE_TYPES,
    RaceType,
    RaceTypeError,
    parse_object_positions,
)

# option -> (RaceType field, type, help)
_OPTIONS = {
    "--objects": ("objects", int, "object avoidance: number of boxes (default 6; DeepRacer on AWS offers 1-6)"),
    "--object-positions": ("object_positions", str, "object avoidance: fixed places, fraction,lane pairs, e.g. "
                                                     "0.25,1;0.5,-1 (lane 1 inner, -1 outer; DR_OA_OBJECT_POSITIONS)"),
    "--min-object-distance": ("min_object_distance", float, "object avoidance: metres between objects (default 2)"),
    "--object-type": ("object_type", str, "object avoidance: box (default) or bot_car (parked cars)"),
    "--bots": ("bots", int, "head-to-bot: number of bot cars (default 3)"),
    "--bot-speed": ("bot_speed", float, "head-to-bot: bot speed in m/s, 0.1-4 (default 0.2)"),
    "--bot-lane": ("bot_lane", str, "head-to-bot: alternate (default), inner, outer or center"),
    "--min-bot-distance": ("min_bot_distance", float, "head-to-bot: metres between bots (default 2)"),
    "--lane-change-min": ("lane_change_min_s", float, "head-to-bot: shortest time between lane changes, s (3)"),
    "--lane-change-max": ("lane_change_max_s", float, "head-to-bot: longest time between lane changes, s (5)"),
    "--lane-change-distance": ("lane_change_distance", float, "head-to-bot: metres a lane change takes (1)"),
    "--collision-penalty": ("collision_penalty", float, "evaluation: seconds a car stands after a crash (5)"),
}
_FLAGS = {"--randomize-objects": ("randomize_objects", "object avoidance: new random places every episode"),
          "--randomize-bots": ("randomize_bots", "head-to-bot: random starting places every episode"),
          "--lane-change": ("lane_change", "head-to-bot: bots change lanes at random intervals")}


def add_race_options(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("race type (DeepRacer's object avoidance and head-to-bot)")
    group.add_argument("--race-type", default=None, metavar="TYPE",
                       help=f"{', '.join(t for t in RACE_TYPES if t != 'head_to_model')} (default time_trial)")
    for option, (_, kind, text) in _OPTIONS.items():
        group.add_argument(option, type=kind, default=None, help=text)
    for option, (_, text) in _FLAGS.items():
        group.add_argument(option, action="store_true", default=False, help=text)


def race_type_from_args(args: argparse.Namespace) -> RaceType | None:
    """The :class:`RaceType` the options describe; None when none was given. Options of a race type
    without ``--race-type`` are refused, naming the option."""
    values = {}
    for option, (name, _, _) in _OPTIONS.items():
        value = getattr(args, option[2:].replace("-", "_"), None)
        if value is not None:
            values[name] = parse_object_positions(value) if name == "object_positions" else value
            values["_option"] = values.get("_option", option)
    for option, (name, _) in _FLAGS.items():
        if getattr(args, option[2:].replace("-", "_"), False):
            values[name] = True
            values["_option"] = values.get("_option", option)
    kind = getattr(args, "race_type", None)
    first = values.pop("_option", None)
    if kind is None:
        if first is not None:
            raise RaceTypeError(f"{first} is an option of a race type: add --race-type object_avoidance or "
                                f"--race-type head_to_bot", field=first)
        return None
    if kind == "head_to_model":
        raise RaceTypeError("--race-type head_to_model races trained models against each other: `laplab race MODEL_A "
                            "MODEL_B`; train for it with object_avoidance or head_to_bot", field="--race-type")
    return RaceType(kind=kind, **values)
