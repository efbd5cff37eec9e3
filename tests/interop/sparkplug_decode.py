"""Decodes Sparkplug B messages with pysparkplug (a decoder independent of rtu2mqtt).

Reads a JSON list of {"topic": ..., "hex": ...} on stdin, in publishing order, and prints a
JSON list with what pysparkplug makes of each: the parsed topic, seq, timestamp and every
metric's name, alias, datatype number, value, null flag, timestamp, historical flag and
String/number properties. Data messages are decoded against the last birth of the same node
or device, as a host does, so alias-only metrics come back with their names.
"""

import json
import sys

try:
    import pysparkplug
    from pysparkplug import _protobuf as protobuf
except ImportError:
    sys.stderr.write(
        "pysparkplug is not installed: run `pip install pysparkplug==0.6.1`\n"
    )
    sys.exit(3)

DECODERS = {
    "NBIRTH": pysparkplug.NBirth,
    "DBIRTH": pysparkplug.DBirth,
    "NDATA": pysparkplug.NData,
    "DDATA": pysparkplug.DData,
    "NDEATH": pysparkplug.NDeath,
    "DDEATH": pysparkplug.DDeath,
    "NCMD": pysparkplug.NCmd,
    "DCMD": pysparkplug.DCmd,
}


def property_value(value):
    kind = value.WhichOneof("value")
    return None if kind is None else getattr(value, kind)


def properties_by_alias_or_name(raw):
    """Metric properties straight from the protobuf message (pysparkplug drops them)."""
    found = {}
    for metric in protobuf.Payload.FromString(raw).metrics:
        if not metric.HasField("properties"):
            continue
        keys = list(metric.properties.keys)
        values = [property_value(v) for v in metric.properties.values]
        found[metric.name] = dict(zip(keys, values))
    return found


def metric_json(metric, properties):
    return {
        "name": metric.name,
        "alias": metric.alias,
        "datatype": int(metric.datatype),
        "value": metric.value,
        "is_null": bool(metric.is_null),
        "timestamp": metric.timestamp,
        "is_historical": bool(metric.is_historical),
        "properties": properties.get(metric.name, {}),
    }


def main():
    births = {}
    out = []
    for message in json.load(sys.stdin):
        topic = pysparkplug.Topic.from_str(message["topic"])
        kind = str(topic.message_type.value if hasattr(topic.message_type, "value") else topic.message_type)
        raw = bytes.fromhex(message["hex"])
        owner = (topic.group_id, topic.edge_node_id, topic.device_id)
        decoder = DECODERS[kind]
        decoded = decoder.decode(raw, birth=births.get(owner))
        if kind in ("NBIRTH", "DBIRTH"):
            births[owner] = decoded
        entry = {
            "type": kind,
            "group": topic.group_id,
            "node": topic.edge_node_id,
            "device": topic.device_id,
        }
        if kind == "NDEATH":
            entry["metrics"] = [metric_json(decoded.bd_seq_metric, {})]
        elif kind == "DDEATH":
            entry["seq"] = decoded.seq
            entry["timestamp"] = decoded.timestamp
            entry["metrics"] = []
        else:
            entry["seq"] = decoded.seq if hasattr(decoded, "seq") else None
            entry["timestamp"] = decoded.timestamp
            properties = properties_by_alias_or_name(raw)
            entry["metrics"] = [metric_json(m, properties) for m in decoded.metrics]
        out.append(entry)
    json.dump(out, sys.stdout)


main()
