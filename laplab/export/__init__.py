"""Exports for DeepRacer's own toolchain: the car's TensorFlow ``model.pb`` and tar.gz, the console's
import layout (see docs/car.md).

- ``policy_layers``: a laplab policy (torch) -> a plain numpy description of its layers (the only
  module here that reads torch modules; it imports torch only through the network it is given);
- ``tensorflow_graph``: that description -> a TensorFlow frozen graph with DeepRacer's node names;
- ``car``: the car's ``.tar.gz``; ``console``: the console / ``dr-upload-model`` folder.

TensorFlow and OpenVINO are imported only inside this package (extra ``deepracer``).
"""
