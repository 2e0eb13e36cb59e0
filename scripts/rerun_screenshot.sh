#!/usr/bin/env bash
# A picture of a Rerun recording taken in a real browser: Rerun's web viewer (shipped in the rerun-sdk wheel)
# serves FILE.rrd, headless Chromium opens it and saves a screenshot.
#
#   scripts/rerun_screenshot.sh FILE.rrd OUT.png [WIDTHxHEIGHT] [SECONDS]
#
# Needs (installs nothing itself): .venv/bin/rerun (make setup: the viz extra), Chromium (Debian: apt-get
# install chromium), curl. WebGL runs on Chromium's software renderer (SwiftShader), so no GPU or display is
# needed. SECONDS (default 25) is how long the page is given to load the viewer and the recording before the
# picture is taken. Ports: the web viewer on $WEB_PORT (default 9190), the recording's gRPC server on
# $GRPC_PORT (default 9877), Chromium's DevTools on $CDP_PORT (default 9222).
set -euo pipefail
rrd=${1:?usage: $0 FILE.rrd OUT.png [WIDTHxHEIGHT] [SECONDS]}
out=${2:?usage: $0 FILE.rrd OUT.png [WIDTHxHEIGHT] [SECONDS]}
size=${3:-1600x1000}
wait_s=${4:-25}
web=${WEB_PORT:-9190}
grpc=${GRPC_PORT:-9877}
cdp=${CDP_PORT:-9222}
here=$(cd "$(dirname "$0")/.." && pwd)
rerun=${RERUN:-$here/.venv/bin/rerun}
chrome=$(command -v chromium || command -v chromium-browser || command -v google-chrome || true)
[ -x "$rerun" ] || { echo "error: $rerun not found (make setup installs rerun-sdk)" >&2; exit 2; }
[ -n "$chrome" ] || { echo "error: Chromium not found (Debian: apt-get install chromium)" >&2; exit 2; }
[ -f "$rrd" ] || { echo "error: $rrd: recording not found" >&2; exit 2; }
log=$(mktemp)
if curl -s -o /dev/null "http://127.0.0.1:$web/" || curl -s -o /dev/null "http://127.0.0.1:$grpc/"; then
  echo "error: port $web or $grpc is in use (another viewer?): set WEB_PORT / GRPC_PORT" >&2; exit 2
fi
# in its own process group: .venv/bin/rerun is a launcher whose child is the viewer binary; both are stopped
setsid "$rerun" --serve-web "$rrd" --web-viewer-port "$web" --port "$grpc" >"$log" 2>&1 &
server=$!
trap 'kill -- -$server 2>/dev/null || true; rm -f "$log"' EXIT
for _ in $(seq 60); do  # until the web viewer answers
  curl -sf -o /dev/null "http://127.0.0.1:$web/" && break
  kill -0 $server 2>/dev/null || { echo "error: the Rerun server stopped:" >&2; cat "$log" >&2; exit 1; }
  sleep 0.5
done
url="http://127.0.0.1:$web/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A$grpc%2Fproxy"
tmp="$out.tmp.png"
profile=$(mktemp -d)
setsid "$chrome" --headless=new --no-sandbox --disable-gpu-sandbox --use-gl=angle --use-angle=swiftshader \
  --enable-unsafe-swiftshader --ignore-gpu-blocklist --hide-scrollbars --window-size="${size/x/,}" \
  --remote-debugging-port="$cdp" --user-data-dir="$profile" about:blank >/dev/null 2>&1 &
browser=$!
trap 'kill -- -$server 2>/dev/null; kill -- -$browser 2>/dev/null; wait 2>/dev/null; rm -rf "$log" "$profile"' EXIT
for _ in $(seq 60); do
  curl -sf -o /dev/null "http://127.0.0.1:$cdp/json/version" && break
  sleep 0.5
done
# Chromium's own --screenshot waits in virtual time, which does not wait for the viewer's WebAssembly: take the
# picture through the DevTools protocol after a real wait
"${PYTHON:-python3}" "$here/scripts/cdp_screenshot.py" "$cdp" "$url" "$tmp" "${size%x*}" "${size#*x}" "$wait_s"
[ -s "$tmp" ] || { echo "error: Chromium took no screenshot of $url" >&2; exit 1; }
mv "$tmp" "$out"
echo "$out: $url ($size)"
