#!/usr/bin/env python3
"""Rewrites spec JSON files with small objects and lists on one line."""
import json
import sys


def fmt(v, indent=0):
    flat = json.dumps(v)
    if len(flat) <= 88 - indent or not isinstance(v, (dict, list)):
        return flat
    pad = " " * (indent + 2)
    if isinstance(v, dict):
        items = [f'{pad}{json.dumps(k)}: {fmt(x, indent + 2)}' for k, x in v.items()]
        return "{\n" + ",\n".join(items) + "\n" + " " * indent + "}"
    items = [pad + fmt(x, indent + 2) for x in v]
    return "[\n" + ",\n".join(items) + "\n" + " " * indent + "]"


for path in sys.argv[1:]:
    with open(path) as f:
        data = json.load(f)
    with open(path, "w") as f:
        f.write(fmt(data) + "\n")
