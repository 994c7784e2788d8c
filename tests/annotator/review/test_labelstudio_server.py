"""The Label Studio round trip against a real server (issue #47): Label Studio 1.23.2 from PyPI, in its own
environment (``tests/_labelstudio_env.py``, built by ``.ci/run``), started on 127.0.0.1 and stopped here.

The run's labelstudio.json and labelstudio_config.xml are imported through the REST API into a project whose
local-files storage serves the video at the URL given with ``--media-url``; a keyframe is added through the API
as a reviewer's annotation of the prediction; the project's JSON export is re-tracked from, and the box must be
in tracks.npz to the pixel. Re-tracking again with the same export must change nothing.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request

import cv2
import numpy as np
import pytest
from _labelstudio_env import LABELSTUDIO
from _runs import snapshot
from typer.testing import CliRunner

from annotator.cli import _with_default_command, app
from annotator.track_store import STORE_NAME, read_store
from sptpt_dev.synthetic import make_clip

USER, PASSWORD, TOKEN = "reviewer@example.com", "sptpt-review-47", "sptpt47token0123456789"
STARTUP_SECONDS = 300  # migrations on a fresh data folder; the test machine may be busy
REQUEST_SECONDS = 60
N = 16
# The reviewer's keyframe: source frame 9 (Label Studio frame 10), in pixels of the 96x72 clip.
FRAME, BOX = 9, (30.0, 20.0, 25.0, 21.0)


def _run(*args):
    result = CliRunner().invoke(app, _with_default_command([str(a) for a in args]))
    return result.exit_code, result.stdout + result.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """The REST API of the started server (urllib: no client library), bounded timeouts, retries on refusal."""

    def __init__(self, url: str) -> None:
        self.url = url

    def call(self, method: str, path: str, *, json_body=None, params=None, auth: bool = True,
             timeout: float = REQUEST_SECONDS) -> bytes:
        url = self.url + path + ("?" + urllib.parse.urlencode(params) if params else "")
        data = None if json_body is None else json.dumps(json_body).encode()
        headers = {"Content-Type": "application/json"} if data is not None else {}
        if auth:
            headers["Authorization"] = f"Token {TOKEN}"
        for attempt in range(3):
            request = urllib.request.Request(url, data=data, headers=headers, method=method)
            try:
                with urllib.request.urlopen(request, timeout=timeout) as response:
                    return response.read()
            except urllib.error.HTTPError as exc:
                raise AssertionError(f"{method} {path}: {exc.code} {exc.read()[:500]!r}") from None
            except (urllib.error.URLError, ConnectionError):
                if attempt == 2:
                    raise
                time.sleep(2)

    def json(self, method: str, path: str, **kwargs):
        return json.loads(self.call(method, path, **kwargs))


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    LABELSTUDIO.require("label-studio")
    return tmp_path_factory.mktemp("labelstudio")


@pytest.fixture(scope="module")
def server(root):
    """Label Studio on a free port of 127.0.0.1, serving local files under ``root/media``; always stopped."""
    port = _free_port()
    env = {**os.environ, "LABEL_STUDIO_LOCAL_FILES_SERVING_ENABLED": "true",
           "LABEL_STUDIO_LOCAL_FILES_DOCUMENT_ROOT": str(root / "media"), "PYTHONDONTWRITEBYTECODE": "1",
           "LABEL_STUDIO_DISABLE_SIGNUP_WITHOUT_LINK": "true",
           # Tests stay off the network: no version check against PyPI, no analytics, no error reporting.
           "LABEL_STUDIO_LATEST_VERSION_CHECK": "false", "LABEL_STUDIO_COLLECT_ANALYTICS": "false",
           "SENTRY_DSN": "", "FRONTEND_SENTRY_DSN": ""}
    (root / "media").mkdir(exist_ok=True)
    log = open(root / "server.log", "wb")
    process = subprocess.Popen(
        [str(LABELSTUDIO.require("label-studio")), "start", "--no-browser", "--internal-host", "127.0.0.1",
         "--port", str(port), "--data-dir", str(root / "data"), "--username", USER, "--password", PASSWORD,
         "--user-token", TOKEN, "--enable-legacy-api-token"],
        stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    try:
        api = Server(f"http://127.0.0.1:{port}")
        deadline = time.monotonic() + STARTUP_SECONDS
        while True:
            if process.poll() is not None:
                raise AssertionError(f"Label Studio exited ({process.returncode}):\n"
                                     f"{(root / 'server.log').read_text(errors='replace')[-3000:]}")
            try:
                api.call("GET", "/health", auth=False, timeout=5)
                api.call("GET", "/api/projects", timeout=10)  # the user and token exist
                break
            except (AssertionError, OSError):
                pass
            if time.monotonic() > deadline:
                raise AssertionError(f"Label Studio did not answer within {STARTUP_SECONDS} s:\n"
                                     f"{(root / 'server.log').read_text(errors='replace')[-3000:]}")
            time.sleep(2)
        yield api
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait(timeout=30)
        log.close()


@pytest.fixture(scope="module")
def run_dir(root):
    """A run on a 16-frame clip, with the video where the project's local-files storage serves it."""
    clip = make_clip(N, size=(96, 72), object_size=(24, 20))
    (root / "seq").mkdir()
    for k, frame in enumerate(clip.frames):
        cv2.imwrite(str(root / "seq" / f"{k:04d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    # The file the reviewer watches; the run reads the same frames from the image folder.
    (root / "media" / "videos").mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(root / "media" / "videos" / "clip.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30.0,
                             (96, 72))
    for frame in clip.frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    (root / "small.yaml").write_text("tracker:\n  n_particles: 60\n  n_negatives: 20\n")
    box = ",".join(f"{v:.2f}" for v in clip.boxes_xywh[0])
    code, output = _run(root / "seq", "--box", box, "--config", root / "small.yaml", "--formats",
                        "otb,coco,flags,labelstudio", "--media-url", "/data/local-files/?d=videos/clip.mp4",
                        "--out", root / "out", "-q")
    assert code == 0, output
    return root / "out"


def test_keyframe_added_through_the_api_comes_back_to_the_pixel_and_only_once(server, run_dir, root, tmp_path):
    tasks = json.loads((run_dir / "labelstudio.json").read_text())
    assert tasks[0]["data"]["video"] == "/data/local-files/?d=videos/clip.mp4"
    project = server.json("POST", "/api/projects", json_body={
        "title": "sptpt review", "label_config": (run_dir / "labelstudio_config.xml").read_text()})
    storage = server.json("POST", "/api/storages/localfiles", json_body={
        "project": project["id"], "title": "videos", "path": str(root / "media" / "videos"),
        "use_blob_urls": False})
    assert storage["id"]
    server.call("POST", f"/api/projects/{project['id']}/import", json_body=tasks)
    listed = server.json("GET", "/api/tasks", params={"project": project["id"]})
    (task,) = listed["tasks"] if isinstance(listed, dict) else listed
    # The video plays: Label Studio serves it at the task's URL.
    assert server.call("GET", task["data"]["video"]) == (root / "media" / "videos" / "clip.mp4").read_bytes()

    # The reviewer accepts the prediction and adds a keyframe with the right box at source frame 9.
    (prediction,) = server.json("GET", "/api/predictions", params={"task": task["id"]})
    result = json.loads(json.dumps(prediction["result"]))
    sequence = result[0]["value"]["sequence"]
    x, y, w, h = BOX
    keyframe = {"frame": FRAME + 1, "x": 100 * x / 96, "y": 100 * y / 72, "width": 100 * w / 96,
                "height": 100 * h / 72, "rotation": 0, "enabled": True, "time": (FRAME + 1) / 30}
    sequence[:] = sorted([k for k in sequence if k["frame"] != FRAME + 1] + [keyframe], key=lambda k: k["frame"])
    server.call("POST", f"/api/tasks/{task['id']}/annotations",
                json_body={"result": result, "parent_prediction": prediction["id"]})
    export = tmp_path / "project-export.json"
    export.write_bytes(server.call("GET", f"/api/projects/{project['id']}/export",
                                   params={"exportType": "JSON", "download_all_tasks": "true"}))

    code, output = _run("retrack", run_dir, "--corrections", export)
    assert code == 0, output
    assert "1 new or changed correction" in output, output
    track = read_store(run_dir / STORE_NAME).tracks[0]
    assert track.keyframe[FRAME]
    np.testing.assert_allclose(track.boxes_xywh[FRAME], BOX, atol=1e-6)
    # Every other human anchor is the first-frame box: the tool's own keyframes did not become anchors.
    assert int(track.keyframe.sum()) == 2

    # What made the second round invent corrections: compared with the re-tracked run instead of the
    # prediction (an export without parent_prediction), the tool's own keyframes after the human one moved.
    data = json.loads(export.read_text())
    assert data[0]["annotations"][0]["parent_prediction"] == prediction["id"]
    data[0]["annotations"][0].update(parent_prediction=None, prediction=None)
    from annotator.review.imports import read_labelstudio_corrections
    from annotator.review.loaded_run import load_run

    run = load_run(run_dir)
    orphan = tmp_path / "without-parent.json"
    orphan.write_text(json.dumps(data))
    frames = range(run.store.start, run.store.stop, run.store.step)
    assert len(read_labelstudio_corrections(orphan, video=run.video, tracks=run.tracks, frames=frames)) > 1
    assert len(read_labelstudio_corrections(export, video=run.video, tracks=run.tracks, frames=frames)) == 1
    assert json.loads((run_dir / "labelstudio.json").read_text())[0]["data"]["video"] == tasks[0]["data"]["video"]

    # The same export again: nothing is new, nothing is written.
    before = snapshot(run_dir)
    code, output = _run("retrack", run_dir, "--corrections", export)
    assert code == 0, output
    assert "every correction is already applied" in output, output
    assert snapshot(run_dir) == before
