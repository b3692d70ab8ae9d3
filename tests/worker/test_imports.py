"""The worker runs the domain code without the web framework: its errors know no HTTP."""

from __future__ import annotations

import json
import subprocess
import sys

WEB_MODULES = ("fastapi", "starlette", "uvicorn", "jinja2")


def test_the_worker_and_the_measurement_child_load_no_web_framework() -> None:
    probe = (
        "import json, sys\n"
        "import worker.__main__, worker.runner, worker.child\n"
        f"print(json.dumps([name for name in {WEB_MODULES!r} if name in sys.modules]))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True
    )
    assert json.loads(done.stdout) == []
    # The probe can fail: the API's modules do load the framework.
    api = probe.replace("import worker.__main__, worker.runner, worker.child", "import service.app")
    done = subprocess.run(
        [sys.executable, "-c", api], capture_output=True, text=True, timeout=120, check=True
    )
    assert "fastapi" in json.loads(done.stdout)
