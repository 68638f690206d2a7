#!/usr/bin/env bash
# `make run`: a user's first model, with the commands the README shows. Starts `nbake serve` (with its
# inference service) on free ports and a fresh data dir, trains a quick `lod` model of the Menger sponge,
# renders the served model through the inference service, and writes into $OUT:
#   artifact/          the artifact's files (weights, report.json, the path-traced reference.png, ...)
#   served.png         the model's frame as the inference service renders it, from the reference's camera
#   side_by_side.png   the path-traced reference | the served frame (enlarged)
#   report.txt         the report's speed-against-error line
# Everything it started is stopped on exit, success or not.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="$PWD/.venv/bin"
OUT="${OUT:-out/run}"

data=$(mktemp -d /tmp/nbake-run-XXXXXX)
server=""
stop() {
    if [[ -n "$server" ]] && kill -0 "$server" 2>/dev/null; then
        kill -TERM "$server" && wait "$server" || true
    fi
    rm -rf "$data"
}
trap stop EXIT
ports=($("$BIN/python" -c "from tests.support.ports import free_port; print(*(free_port() for _ in range(4)))"))

"$BIN/nbake" serve --data-dir "$data" --port "${ports[0]}" --grpc-port "${ports[1]}" \
    --inference-port "${ports[2]}" --inference-grpc-port "${ports[3]}" --log-level warning &
server=$!
export NBAKE_URL="http://127.0.0.1:${ports[0]}" NBAKE_INFERENCE_URL="http://127.0.0.1:${ports[2]}"
ready() { "$BIN/python" -c "import sys, urllib.request; urllib.request.urlopen(sys.argv[1], timeout=2)" "$1" 2>/dev/null; }
for _ in $(seq 240); do
    ready "$NBAKE_URL/readyz" && ready "$NBAKE_INFERENCE_URL/readyz" && break
    kill -0 "$server" || { echo "nbake serve exited" >&2; exit 1; }
    sleep 0.5
done
export NBAKE_TOKEN=$(cat "$data/admin-token")

rm -rf "$OUT" && mkdir -p "$OUT"
job=$("$BIN/nbake" submit menger_sponge --kind lod --preset quick --json | "$BIN/python" -c "import json,sys; print(json.load(sys.stdin)['job']['id'])")
"$BIN/nbake" watch "$job"
"$BIN/nbake" download "$job" -o "$OUT/artifact"
# the served model from the artifact's camera at its reference's size, so the two compare pixel for pixel
"$BIN/python" - "$OUT" <<'PY'
import json, sys
from pathlib import Path
import yaml
from PIL import Image

out = Path(sys.argv[1])
camera = json.loads((out / "artifact/scene.json").read_text())["spec"]["camera"]
camera["width"], camera["height"] = Image.open(out / "artifact/reference.png").size
(out / "camera.yaml").write_text(yaml.safe_dump(camera))
PY
"$BIN/nbake" render "$job" --camera "$OUT/camera.yaml" --set level=0 -o "$OUT/served.png"  # the LoD the report measures
"$BIN/python" - "$OUT" <<'PY'
import json, sys
from pathlib import Path
from PIL import Image

out = Path(sys.argv[1])
reference, served = Image.open(out / "artifact/reference.png"), Image.open(out / "served.png")
both = Image.new("RGB", (reference.width * 2, reference.height))
both.paste(reference.convert("RGB"), (0, 0))
both.paste(served.convert("RGB"), (reference.width, 0))
zoom = max(1, 256 // reference.height)  # small evaluation views, enlarged to be seen
both.resize((both.width * zoom, both.height * zoom), Image.NEAREST).save(out / "side_by_side.png")
report = json.loads((out / "artifact/report.json").read_text())
model, equal = report["model"], report["path_tracing_equal_time"]
line = (
    f"{report['kind']} ({model['label']}): {model['seconds_per_frame'] * 1e3:.0f} ms a frame at FLIP "
    f"{model['error']['flip']:.3f}; path tracing in the same time ({equal['label']}): FLIP "
    f"{equal['error']['flip']:.3f}"
)
(out / "report.txt").write_text(line + "\n")
print(line)
print(f"wrote {out}/side_by_side.png: the path-traced reference | the model served by the inference service")
PY
