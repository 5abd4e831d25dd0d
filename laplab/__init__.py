"""laplab: a local, open and fast re-implementation of the AWS DeepRacer platform."""

__version__ = "0.1.0"
