"""The car: parameters, batched dynamics, footprint."""

from laplab.vehicle.params import DEEPRACER, VehicleParams, vehicle_preset

__all__ = ["DEEPRACER", "VehicleParams", "vehicle_preset"]
