"""``python -m worker``: run one worker until SIGTERM or Ctrl-C (what ``canopy worker`` starts)."""

from __future__ import annotations

import logging
import signal
import sys
from types import FrameType

from service.context import Context
from service.migrate import is_current
from service.settings import Settings
from worker.runner import Worker


def main() -> None:
    """Run a worker on the database the ``CANOPY_*`` settings name."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    context = Context.from_settings(Settings())
    if not is_current(context.database):
        sys.stderr.write(
            "error: the database is not initialised or not at the newest schema; start `canopy serve` "
            "(or `canopy up`) once to migrate it\n"
        )
        sys.exit(2)
    worker = Worker(context, name=sys.argv[1] if len(sys.argv) > 1 else None)

    def stop(_signal: int, _frame: FrameType | None) -> None:
        worker.stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    worker.run_forever()
    context.database.dispose()


if __name__ == "__main__":
    main()
