#!/usr/bin/env python3
"""Regenerates data/sunspec/models.json from the SunSpec Alliance's model definitions.

The SunSpec Alliance publishes every information model as JSON in its public repository
https://github.com/sunspec/models (json/model_<id>.json). This script keeps, for the models
`rtu2mqtt sunspec` writes profiles for, only what a profile needs: each point's name, type,
size in registers, scale factor point, units and label, and the repeating group with its own
points. Symbols, descriptions and conformance notes are left out to keep the table small.

Usage: scripts/sunspec-models.py PATH-TO-sunspec/models [COMMIT] > data/sunspec/models.json
The unit test `profile::sunspec::tests::table_matches_the_published_lengths` checks the result.
"""
import json
import sys

MODELS = [1, 101, 102, 103, 111, 112, 113, 120, 121, 122, 123, 124, 160, 201, 202, 203, 204]

# Short field-name prefixes: a written profile names a field `<prefix>_<point>`.
PREFIX = {1: "common", 101: "inverter", 102: "inverter", 103: "inverter", 111: "inverter",
          112: "inverter", 113: "inverter", 120: "nameplate", 121: "settings",
          122: "status", 123: "controls", 124: "storage", 160: "mppt", 201: "meter",
          202: "meter", 203: "meter", 204: "meter"}


def point(p):
    out = {"name": p["name"], "type": p["type"], "size": p["size"]}
    for key in ("sf", "units", "label"):
        if key in p:
            out[key] = p[key]
    return out


def main():
    root = sys.argv[1]
    commit = sys.argv[2] if len(sys.argv) > 2 else "unknown"
    models = []
    for mid in MODELS:
        with open(f"{root}/json/model_{mid}.json", encoding="utf-8") as f:
            group = json.load(f)["group"]
        entry = {"id": mid, "name": group["name"], "label": group.get("label", ""),
                 "prefix": PREFIX[mid], "points": [point(p) for p in group["points"]]}
        repeating = group.get("groups", [])
        if len(repeating) > 1:
            raise SystemExit(f"model {mid}: more than one repeating group")
        if repeating:
            entry["repeating"] = {"name": repeating[0]["name"],
                                  "points": [point(p) for p in repeating[0]["points"]]}
        models.append(entry)
    table = {"source": f"https://github.com/sunspec/models commit {commit}", "models": models}
    # One point a line: a regenerated table diffs point by point.
    compact = lambda value: json.dumps(value, separators=(",", ":"), ensure_ascii=False)
    out = sys.stdout
    out.write('{"source":%s,"models":[\n' % compact(table["source"]))
    for i, model in enumerate(models):
        head = {k: v for k, v in model.items() if k not in ("points", "repeating")}
        out.write(compact(head)[:-1] + ',"points":[\n')
        out.write(",\n".join(compact(p) for p in model["points"]) + "]")
        if "repeating" in model:
            rep = model["repeating"]
            out.write(',"repeating":{"name":%s,"points":[\n' % compact(rep["name"]))
            out.write(",\n".join(compact(p) for p in rep["points"]) + "]}")
        out.write("}" + (",\n" if i + 1 < len(models) else "\n"))
    out.write("]}\n")


if __name__ == "__main__":
    main()
