#!/usr/bin/env bash
# Set-up and everyday tasks, from a fresh Debian machine: `./dev.sh run` and `./dev.sh test`.
# Installs the system libraries Open3D needs (apt, with sudo when not root), a virtual environment in
# .venv and the project with its development tools; then runs the task. Re-running skips what is done.
set -euo pipefail
cd "$(dirname "$0")"

VENV=${CANOPY_VENV:-.venv}
APT_PACKAGES=(libusb-1.0-0 libgl1 libgomp1 curl openssl)
TEST_APT_PACKAGES=(chromium)  # the page tests' browser, driven by Playwright
PYTHON=${PYTHON:-python3}

as_root() { if [ "$(id -u)" -eq 0 ]; then "$@"; else sudo "$@"; fi; }

system_libraries() {
    local missing=()
    for package in "${APT_PACKAGES[@]}" "$@"; do
        dpkg -s "$package" >/dev/null 2>&1 || missing+=("$package")
    done
    command -v "$PYTHON" >/dev/null 2>&1 || missing+=(python3)
    "$PYTHON" -c 'import ensurepip, venv' >/dev/null 2>&1 || missing+=(python3-venv)
    if [ ${#missing[@]} -gt 0 ]; then
        echo "installing system packages: ${missing[*]}"
        as_root apt-get update -qq
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
    fi
}

python_environment() {
    local stamp="$VENV/.canopy-installed"
    if [ -f "$stamp" ] && [ "$stamp" -nt pyproject.toml ]; then return; fi
    [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
    "$VENV/bin/python" -m pip install --quiet --upgrade pip
    "$VENV/bin/python" -m pip install --quiet -e ".[dev]"
    touch "$stamp"
}

setup() { system_libraries; python_environment; }

# The scale path's tests need a PostgreSQL server. CANOPY_TEST_POSTGRES_URL names one; else the local
# server on 127.0.0.1:5432 is used when it lets user postgres into database test without a password; else
# Debian's PostgreSQL is installed (when missing), its cluster started, and a role and database
# canopy_test made for the tests. When none of this works the tests say so and skip.
postgres_for_tests() {
    if [ -n "${CANOPY_TEST_POSTGRES_URL:-}" ]; then return; fi
    local probe='import psycopg; psycopg.connect("host=127.0.0.1 user=postgres dbname=test", connect_timeout=3)'
    if "$VENV/bin/python" -c "$probe" 2>/dev/null; then return; fi
    if ! ls /usr/lib/postgresql/*/bin/postgres >/dev/null 2>&1; then
        echo "installing PostgreSQL for the scale path's tests"
        as_root apt-get update -qq
        as_root env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq postgresql >/dev/null \
            || { echo "PostgreSQL could not be installed: its tests will be skipped" >&2; return; }
    fi
    local version name port
    read -r version name port _ <<<"$(pg_lsclusters -h | sort -V | tail -1)"
    if [ -z "${port:-}" ]; then echo "no PostgreSQL cluster: its tests will be skipped" >&2; return; fi
    as_root pg_ctlcluster "$version" "$name" start >/dev/null 2>&1 || true  # already running is fine
    as_root runuser -u postgres -- psql -q -p "$port" -v ON_ERROR_STOP=1 >/dev/null <<'SQL' \
        || { echo "PostgreSQL did not take the test role: its tests will be skipped" >&2; return; }
SELECT 'CREATE ROLE canopy_test LOGIN PASSWORD ''canopy_test'''
WHERE NOT EXISTS (SELECT FROM pg_roles WHERE rolname = 'canopy_test') \gexec
SELECT 'CREATE DATABASE canopy_test OWNER canopy_test'
WHERE NOT EXISTS (SELECT FROM pg_database WHERE datname = 'canopy_test') \gexec
SQL
    export CANOPY_TEST_POSTGRES_URL="postgresql+psycopg://canopy_test:canopy_test@127.0.0.1:$port/canopy_test"
}

# Send one capture folder to the service with curl, as capture software would: create the capture, PUT each
# file with its SHA-256 (RFC 9530 Content-Digest), start the job. Prints the job's address.
send_capture() {
    local server=$1 key=$2 folder=$3 capture file digest
    capture=$(curl -sf -H "Authorization: Bearer $key" -H "Content-Type: application/json" \
        --data-binary "@$folder/capture.json" "$server/v1/captures" | sed -E 's/^\{"id":([0-9]+).*/\1/')
    for file in "$folder"/views/*/*; do
        digest=$(openssl dgst -sha256 -binary "$file" | base64)
        curl -sf -o /dev/null -X PUT -H "Authorization: Bearer $key" -H "Content-Digest: sha-256=:$digest:" \
            --data-binary "@$file" "$server/v1/captures/$capture/files/${file#"$folder"/}"
    done
    curl -sf -D - -o /dev/null -X POST -H "Authorization: Bearer $key" "$server/v1/captures/$capture/jobs" \
        | tr -d '\r' | sed -n 's/^[Ll]ocation: //p'
}

case "${1:-}" in
    run)
        setup
        # The main job on the embedded default: `canopy up` (API and one worker on SQLite in the data
        # folder), a simulated two-view capture sent to it with curl, its measurement printed.
        export CANOPY_DATA_DIR=${CANOPY_DATA_DIR:-./canopy-data}
        port=${CANOPY_PORT:-8000}
        server="http://127.0.0.1:$port"
        demo="$CANOPY_DATA_DIR/demo"
        rm -rf "$demo"
        "$VENV/bin/canopy" simulate "$demo" --seed 7 --count 1 >/dev/null
        # Captured now: each run sends a new capture of the demo tree (the service keeps one capture per
        # tree and time; the one an earlier run sent belongs to that run's key).
        "$VENV/bin/python" - "$demo/tree_000/capture.json" <<'PY'
import datetime, json, sys
manifest = json.load(open(sys.argv[1]))
manifest["captured_at"] = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
json.dump(manifest, open(sys.argv[1], "w"), indent=2)
PY
        if curl -s -o /dev/null "$server/healthz"; then
            echo "something already answers on $server (an earlier canopy up?); stop it or set CANOPY_PORT" >&2
            exit 1
        fi
        "$VENV/bin/canopy" up --port "$port" &
        up_pid=$!
        trap 'kill $up_pid 2>/dev/null; wait $up_pid 2>/dev/null' EXIT
        until curl -sf "$server/healthz" >/dev/null; do
            kill -0 $up_pid 2>/dev/null || { echo "canopy up did not start" >&2; exit 1; }
            sleep 0.2
        done
        key=$("$VENV/bin/canopy" keys create --scope capture --scope read --name dev.sh-run 2>/dev/null | tail -1)
        job=$(send_capture "$server" "$key" "$demo/tree_000")
        [ -n "$job" ] || { echo "sending the demo capture to $server failed (see the service's log above)" >&2; exit 1; }
        echo "measurement job: $server$job"
        until curl -sf -H "Authorization: Bearer $key" "$server$job" | grep -qE '"state":"(succeeded|failed)"'; do
            sleep 0.2
        done
        curl -sf -H "Authorization: Bearer $key" "$server$job" | "$VENV/bin/python" -c "$(cat <<'PY'
import json, sys, urllib.request
job = json.load(sys.stdin)
if job["state"] != "succeeded":
    sys.exit(f"job failed: {job['error']}")
request = urllib.request.Request(f"{sys.argv[1]}/v1/measurements/{job['measurement_id']}",
                                 headers={"Authorization": f"Bearer {sys.argv[2]}"})
measured = json.load(urllib.request.urlopen(request))
truth = json.load(open(sys.argv[3]))
print("measured:     H %.3f  W %.3f  D %.3f m" % (measured["height_m"], measured["width_m"], measured["thickness_m"]))
print("ground truth: H %.3f  W %.3f  D %.3f m" % (truth["height_m"], truth["width_m"], truth["thickness_m"]))
print(f"fused cloud:  {sys.argv[1]}/v1/measurements/{job['measurement_id']}/cloud.ply")
print(f"report:       {sys.argv[1]}/v1/measurements/{job['measurement_id']}/report")
PY
)" "$server" "$key" "$demo/tree_000/ground_truth.json"
        echo "Dashboard and reports: $server/ (sign in with the key $key)"
        echo "Send capture folders from the laptop: .venv/bin/canopy upload FOLDER --server $server --key $key --wait"
        echo "The service keeps running at $server (API docs: $server/docs); Ctrl-C stops it."
        wait $up_pid
        ;;
    test)
        system_libraries "${TEST_APT_PACKAGES[@]}"
        python_environment
        postgres_for_tests
        shift
        "$VENV/bin/python" -m pytest -q "$@"
        ;;
    *)
        echo "usage: ./dev.sh run | ./dev.sh test [pytest args]" >&2
        exit 64
        ;;
esac
