"""Load our exports with third-party readers; run by ``_reader_env.run_check`` inside ``tests/_reader_env``.

Usage: ``python _reader_checks.py CHECK '{"path": ...}'``; prints one JSON line with what the reader saw,
so that the test (in the project's environment) makes the assertions.
"""

from __future__ import annotations

import json
import sys


def datumaro_dataset(path: str, fmt: str) -> dict:
    import datumaro as dm

    dataset = dm.Dataset.import_from(path, fmt)
    labels = dataset.categories()[dm.AnnotationType.label]
    items = []
    for item in dataset:
        boxes = []
        for ann in item.annotations:
            if ann.type != dm.AnnotationType.bbox:
                continue
            attrs = {k: v for k, v in ann.attributes.items() if isinstance(v, (bool, int, float, str))}
            boxes.append({"label": labels[ann.label].name, "xywh": [ann.x, ann.y, ann.w, ann.h], "attributes": attrs})
        items.append({"id": str(item.id), "frame": item.attributes.get("frame"), "boxes": boxes})
    return {"items": items, "labels": [label.name for label in labels]}


def motmetrics_loadtxt(path: str) -> dict:
    import motmetrics as mm

    frame = mm.io.loadtxt(path, fmt="mot15-2D")
    rows = [[int(f), int(i), *map(float, row)] for (f, i), row in
            zip(frame.index, frame[["X", "Y", "Width", "Height", "Confidence"]].to_numpy())]
    return {"rows": rows}


CHECKS = {
    "datumaro_cvat": lambda args: datumaro_dataset(args["path"], "cvat"),
    "datumaro_mot": lambda args: datumaro_dataset(args["path"], "mot_seq"),
    "motmetrics": lambda args: motmetrics_loadtxt(args["path"]),
}

if __name__ == "__main__":
    check, args = sys.argv[1], json.loads(sys.argv[2])
    print(json.dumps(CHECKS[check](args)))
