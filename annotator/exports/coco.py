"""COCO detection JSON with the video fields of TAO, mmtracking's CocoVID and CVAT.

The layout follows FORMATS.md ("COCO with video fields") field by field. The
choices it leaves open:

* **Images.** One image per processed frame (the union over tracks), in
  source order. ``frame_id`` is the 0-based position in that list (CocoVID);
  ``frame_index`` the source frame index (TAO). ``file_name`` is, for an
  image-folder source, the real image's path relative to the parent of the
  sequence folder (``VideoInfo.frame_files``, e.g. ``Coke/img/0001.jpg``
  for an OTB sequence), so a COCO viewer given that parent folder as image
  root finds the images. For a video it is ``<video name>/<frame_index:06d>.jpg``:
  this exporter writes no images, and that is the name
  ``ffmpeg -i VIDEO -fps_mode passthrough -start_number 0 NAME/%06d.jpg`` gives each decoded frame
  (without passthrough, ffmpeg duplicates or drops frames of a variable frame rate video).
* **Boxes** are 0-based ``xywh``, clipped to the image, rounded to 1/1000
  pixel. A frame whose object is ``outside`` gets no annotation; so does a
  box that is NaN or lies wholly outside the image after clipping (COCO has
  no "absent" box, and zero-area boxes break trainers). Such frames remain
  in ``images`` and in the flags file.
* **Categories** get ids 1.. in order of first appearance of the labels over
  the tracks, unless ``categories`` fixes them.
* **Tracks** keep their ``TrackResult.track_id`` as COCO track id unless
  ``first_track_id`` renumbers them; ``track_id``, ``instance_id`` and
  ``attributes.track_id`` of an annotation are that id.
* **Ids** start at the ``first_*`` arguments so that files of many videos can
  be concatenated; :func:`merge_coco` renumbers everything in one go.

The file is written one list element per line, so that it diffs well and
stays compact.
"""

from __future__ import annotations

import json
import os
from typing import Any, Mapping, Sequence

import numpy as np

from annotator.atomic import write_text_atomic
from annotator.tracks import TrackResult, VideoInfo
from sptpt.boxes import clip_xywh

__all__ = ["DEFAULT_LABEL", "build_coco", "dumps_coco", "merge_coco", "save_coco", "write_coco"]

#: Category used when nothing else is named.
DEFAULT_LABEL = "object"

_DECIMALS = 3  # pixels: 1/1000 px is far below any annotation's accuracy, and keeps the file small
_SCORE_DECIMALS = 4


def _categories(tracks: Sequence[TrackResult], categories: Sequence[str | Mapping] | None) -> list[dict]:
    if categories is None:
        names: list[str] = []
        for track in tracks:
            if track.label not in names:
                names.append(track.label)
        names = names or [DEFAULT_LABEL]
        return [{"id": i, "name": n, "supercategory": n} for i, n in enumerate(names, start=1)]
    result: list[dict] = []
    for i, item in enumerate(categories, start=1):
        if isinstance(item, str):
            result.append({"id": i, "name": item, "supercategory": item})
        else:
            entry = dict(item)
            if "name" not in entry:
                raise ValueError(f"category {item!r} has no 'name'; expected a label or a dict with 'id' and 'name'")
            entry.setdefault("id", i)
            entry.setdefault("supercategory", entry["name"])
            result.append(entry)
    ids = [c["id"] for c in result]
    names = [c["name"] for c in result]
    if len(set(ids)) != len(ids) or len(set(names)) != len(names):
        raise ValueError(f"categories must have unique ids and names, got ids {ids} and names {names}")
    missing = sorted({t.label for t in tracks} - set(names))
    if missing:
        raise ValueError(f"track labels {missing} are not among categories {names}; add them or relabel the tracks")
    return result


def _file_name(video: VideoInfo, frame_index: int) -> str:
    """COCO ``file_name`` of a source frame: the image folder's own file, else the ffmpeg frame-dump name."""
    if video.frame_files is not None:
        return video.frame_files[frame_index]
    return f"{video.name}/{frame_index:06d}.jpg"


def _check_positive_id(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1 (COCO ids start at 1), got {value!r}")
    return int(value)


def build_coco(
    video: VideoInfo,
    tracks: Sequence[TrackResult],
    *,
    video_id: int = 1,
    first_image_id: int = 1,
    first_annotation_id: int = 1,
    first_track_id: int | None = None,
    categories: Sequence[str | Mapping] | None = None,
    info: Mapping[str, Any] | None = None,
) -> dict:
    """Build the COCO-with-video dict for one video.

    Parameters
    ----------
    video : VideoInfo
        The source: name, size, fps and decoded frame count.
    tracks : sequence of TrackResult
        The tracked objects; their frame indices must lie inside the video.
    video_id, first_image_id, first_annotation_id : int
        First ids to use (>= 1), so that several videos can share id spaces.
    first_track_id : int or None
        Renumber tracks from this id in the given order; None keeps
        ``TrackResult.track_id``.
    categories : sequence of str or dict, or None
        Category names (ids 1.. in order) or COCO category dicts; None derives
        them from the track labels.
    info : mapping or None
        Entries that override or extend the default ``info`` (e.g. ``date_created``).

    Returns
    -------
    dict
        Keys ``info, licenses, categories, videos, images, tracks, annotations``;
        plain Python types, ready for ``json.dump``.
    """
    video_id = _check_positive_id("video_id", video_id)
    first_image_id = _check_positive_id("first_image_id", first_image_id)
    first_annotation_id = _check_positive_id("first_annotation_id", first_annotation_id)
    tracks = list(tracks)
    track_ids = _coco_track_ids(video, tracks, first_track_id)

    category_list = _categories(tracks, categories)
    category_id = {c["name"]: c["id"] for c in category_list}

    frame_indices = np.unique(np.concatenate([t.frame_indices for t in tracks])) if tracks else np.zeros(0, np.int64)
    image_id = {int(f): first_image_id + k for k, f in enumerate(frame_indices)}
    images = _images(video, frame_indices, image_id, video_id)

    annotations = _annotations(video, tracks, track_ids, image_id, category_id, video_id, first_annotation_id)

    default_info = {
        "description": f"sptpt-annotate boxes for {video.name}",
        "version": "1.0",
        "contributor": "sptpt-annotate",
        "url": "",
        "bbox_format": "xywh, 0-based pixels",
    }
    return {
        "info": {**default_info, **dict(info or {})},
        "licenses": [],
        "categories": category_list,
        "videos": [
            {
                "id": video_id,
                "name": video.name,
                "width": video.width,
                "height": video.height,
                "fps": video.fps,
                "length": video.frame_count,
            }
        ],
        "images": images,
        "tracks": [
            {"id": tid, "category_id": category_id[t.label], "video_id": video_id} for t, tid in zip(tracks, track_ids)
        ],
        "annotations": annotations,
    }


def _coco_track_ids(video: VideoInfo, tracks: list[TrackResult], first_track_id: int | None) -> list[int]:
    """The tracks' COCO ids (their own, or renumbered from ``first_track_id``), checked with the tracks' frames."""
    if first_track_id is None:
        track_ids = [t.track_id for t in tracks]
    else:
        first_track_id = _check_positive_id("first_track_id", first_track_id)
        track_ids = list(range(first_track_id, first_track_id + len(tracks)))
    if len(set(track_ids)) != len(track_ids):
        raise ValueError(f"track ids must be unique within a video, got {track_ids}; renumber with first_track_id=1")
    for track in tracks:
        if len(track) and track.frame_indices[-1] >= video.frame_count:
            raise ValueError(
                f"track {track.track_id} has frame index {int(track.frame_indices[-1])} but {video.name!r} has "
                f"{video.frame_count} frames; expected tracks computed on this video"
            )
    return track_ids


def _images(video: VideoInfo, frame_indices: np.ndarray, image_id: dict[int, int], video_id: int) -> list[dict]:
    """One image per processed frame, ``frame_id`` counting them from 0."""
    return [
        {
            "id": image_id[int(f)],
            "video_id": video_id,
            "file_name": _file_name(video, int(f)),
            "width": video.width,
            "height": video.height,
            "frame_id": k,
            "frame_index": int(f),
        }
        for k, f in enumerate(frame_indices)
    ]


def _annotations(video: VideoInfo, tracks: list[TrackResult], track_ids: list[int], image_id: dict[int, int],
                 category_id: dict[str, int], video_id: int, first_annotation_id: int) -> list[dict]:
    """One annotation per row with a box inside the frame (none where the object is outside)."""
    # Annotations in frame order, then track order, so that ids follow the video.
    rows = []
    for t, (track, tid) in enumerate(zip(tracks, track_ids)):
        for i in range(len(track)):
            rows.append((int(track.frame_indices[i]), t, i, tid))
    rows.sort()
    annotations: list[dict] = []
    for frame, t, i, tid in rows:
        track = tracks[t]
        if track.outside[i]:
            continue
        clipped = clip_xywh(track.boxes_xywh[i], video.width, video.height, decimals=_DECIMALS)
        if clipped is None:
            continue
        bbox = list(clipped)
        score = round(float(track.confidence[i]), _SCORE_DECIMALS)
        cat = category_id[track.label]
        annotations.append(
            {
                "id": first_annotation_id + len(annotations),
                "image_id": image_id[frame],
                "video_id": video_id,
                "category_id": cat,
                "bbox": bbox,
                "area": round(bbox[2] * bbox[3], _DECIMALS),
                "iscrowd": 0,
                "segmentation": [],
                "track_id": tid,
                "instance_id": tid,
                "score": score,
                "attributes": {
                    "track_id": tid,
                    "keyframe": bool(track.keyframe[i]),
                    "outside": False,  # outside frames have no annotation; kept for CVAT's attribute set
                    "occluded": bool(track.occluded[i]),
                    "score": score,
                    "needs_review": bool(track.flagged[i]),
                },
            }
        )
    return annotations


def merge_coco(datasets: Sequence[Mapping]) -> dict:
    """Merge COCO-with-video dicts of several videos into one, renumbering every id from 1.

    Categories are merged by name (ids 1.. in order of first appearance);
    videos, images, tracks and annotations are renumbered in input order and
    every reference (``video_id``, ``image_id``, ``category_id``,
    ``track_id``, ``instance_id``, ``attributes.track_id``) follows. ``info``
    is the first dataset's; licenses are the union.

    Raises
    ------
    ValueError
        Two videos with the same name: their ``file_name`` entries would clash.
    """
    datasets = list(datasets)
    if not datasets:
        raise ValueError("merge_coco needs at least one dataset, got none")
    merged: dict[str, Any] = {
        "info": dict(datasets[0].get("info", {})),
        "licenses": [],
        "categories": [],
        "videos": [],
        "images": [],
        "tracks": [],
        "annotations": [],
    }
    category_by_name: dict[str, int] = {}
    seen_videos: dict[str, int] = {}
    for n, data in enumerate(datasets):
        for lic in data.get("licenses", []):
            if lic not in merged["licenses"]:
                merged["licenses"].append(dict(lic))
        cat_map = {}
        for cat in data.get("categories", []):
            if cat["name"] not in category_by_name:
                category_by_name[cat["name"]] = len(category_by_name) + 1
                merged["categories"].append({**cat, "id": category_by_name[cat["name"]]})
            cat_map[cat["id"]] = category_by_name[cat["name"]]
        video_map = {}
        for vid in data.get("videos", []):
            if vid["name"] in seen_videos:
                raise ValueError(
                    f"video name {vid['name']!r} occurs in datasets {seen_videos[vid['name']]} and {n}; image file "
                    f"names would clash - give the videos unique names (e.g. prefix the folder) before merging"
                )
            seen_videos[vid["name"]] = n
            video_map[vid["id"]] = len(merged["videos"]) + 1
            merged["videos"].append({**vid, "id": video_map[vid["id"]]})
        image_map = {}
        for image in data.get("images", []):
            image_map[image["id"]] = len(merged["images"]) + 1
            merged["images"].append({**image, "id": image_map[image["id"]], "video_id": video_map[image["video_id"]]})
        track_map = {}
        for track in data.get("tracks", []):
            track_map[track["id"]] = len(merged["tracks"]) + 1
            merged["tracks"].append(
                {
                    **track,
                    "id": track_map[track["id"]],
                    "category_id": cat_map[track["category_id"]],
                    "video_id": video_map[track["video_id"]],
                }
            )
        for ann in data.get("annotations", []):
            merged["annotations"].append(_renumbered_annotation(ann, len(merged["annotations"]) + 1, image_map,
                                                                cat_map, video_map, track_map))
    if len(datasets) > 1:
        merged["info"]["description"] = f"sptpt-annotate boxes for {len(merged['videos'])} videos"
    return merged


def _renumbered_annotation(ann: Mapping, new_id: int, image_map: dict, cat_map: dict, video_map: dict,
                           track_map: dict) -> dict:
    """``ann`` with its id and every id it refers to renumbered into the merged dataset."""
    new = {
        **ann,
        "id": new_id,
        "image_id": image_map[ann["image_id"]],
        "category_id": cat_map[ann["category_id"]],
    }
    if "video_id" in ann:
        new["video_id"] = video_map[ann["video_id"]]
    for key in ("track_id", "instance_id"):
        if key in ann:
            new[key] = track_map[ann[key]]
    if "attributes" in ann:
        new["attributes"] = dict(ann["attributes"])
        if "track_id" in new["attributes"]:
            new["attributes"]["track_id"] = track_map[ann["attributes"]["track_id"]]
    return new


def dumps_coco(dataset: Mapping) -> str:
    """Serialise a COCO dict as strict JSON (no NaN), one list element per line."""
    parts = []
    for key, value in dataset.items():
        if isinstance(value, list) and value:
            body = "[\n" + ",\n".join(json.dumps(v, ensure_ascii=False, allow_nan=False) for v in value) + "\n]"
        else:
            body = json.dumps(value, ensure_ascii=False, allow_nan=False)
        parts.append(f"{json.dumps(key)}: {body}")
    return "{\n" + ",\n".join(parts) + "\n}\n"


def save_coco(path: str | os.PathLike, dataset: Mapping) -> None:
    """Write a COCO dict (e.g. from :func:`merge_coco`) to ``path`` atomically."""
    write_text_atomic(path, dumps_coco(dataset))


def write_coco(path: str | os.PathLike, video: VideoInfo, tracks: Sequence[TrackResult], **kwargs: Any) -> dict:
    """Build the COCO dict of one video (keywords as :func:`build_coco`), write it atomically, return it."""
    dataset = build_coco(video, tracks, **kwargs)
    save_coco(path, dataset)
    return dataset
