"""``python -m sepfm_ros`` is the ``sepfm_ros`` console command."""

from sepfm_ros.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
