"""The weights inside a frozen TensorFlow graph (a car's ``model.pb``), read with numpy alone.

DeepRacer freezes its policy with TensorFlow's ``convert_variables_to_constants``: every variable
becomes a ``Const`` node of the same name (``main_level/agent/main/online/network_1/...``), so the
policy network's weights come out under rl_coach's variable names, as a checkpoint's do (the value
network is not in the graph: the car does not need it). A GraphDef is a protocol buffer: ``node``
(field 1) NodeDefs with ``name`` (1), ``op`` (2) and ``attr`` (5, a map); a Const's ``value``
attribute holds a TensorProto (dtype 1, shape 2, ``tensor_content`` 4 or ``float_val`` 5).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from laplab.export.checkpoint_bundle import DTYPES, BundleError, _fields, tensor_shape


def _tensor(data: bytes, where: str) -> np.ndarray | None:
    dtype, shape, content, floats = 0, [], None, []
    for number, wire, value in _fields(data, where):
        if number == 1:
            dtype = value
        elif number == 2:
            shape = tensor_shape(value, where)
        elif number == 4:
            content = value
        elif number == 5 and wire == 2:
            floats.extend(np.frombuffer(value, "<f4").tolist())
        elif number == 5 and wire == 5:
            floats.append(float(np.frombuffer(int(value).to_bytes(4, "little"), "<f4")[0]))
    if dtype not in DTYPES:
        return None
    count = int(np.prod(shape, dtype=np.int64))
    if content is not None:
        array = np.frombuffer(content, dtype=np.dtype(DTYPES[dtype]).newbyteorder("<")).astype(DTYPES[dtype])
        if array.size != count:
            raise BundleError(f"{where}: a constant holds {array.size} values for shape {shape}; the graph is damaged.")
        return array.reshape(shape)
    if dtype == 1:  # float_val: one value repeated, or all of them
        values = np.asarray(floats or [0.0], np.float32)
        return (np.full(count, values[0], np.float32) if values.size == 1 else values).reshape(shape)
    return None


def graph_constants(path: str | Path) -> dict[str, np.ndarray]:
    """``{node name: array}`` of every float ``Const`` node of the GraphDef in ``path``."""
    where = str(path)
    data = Path(path).read_bytes()
    constants: dict[str, np.ndarray] = {}
    try:
        for number, wire, node in _fields(data, where):
            if number != 1 or wire != 2:
                continue
            name, op, value = "", "", None
            for field, _, content in _fields(node, where):
                if field == 1:
                    name = content.decode("utf-8", "replace")
                elif field == 2:
                    op = content.decode("utf-8", "replace")
                elif field == 5:  # map entry: key 1, AttrValue 2
                    entry = dict((n, v) for n, _, v in _fields(content, where))
                    if entry.get(1) == b"value" and isinstance(entry.get(2), bytes):
                        value = next((v for n, _, v in _fields(entry[2], where) if n == 8), None)
            if op == "Const" and value is not None:
                array = _tensor(value, where)
                if array is not None and array.dtype == np.float32:
                    constants[name] = array
    except BundleError:
        raise
    except (ValueError, IndexError, OverflowError) as exc:
        raise BundleError(f"{where}: not a TensorFlow GraphDef ({type(exc).__name__}: {exc}).") from None
    if not constants:
        raise BundleError(f"{where}: no weights found (no float Const nodes); not a frozen DeepRacer model.pb.")
    return constants
