"""Dynamixel X-series servos over Protocol 2.0, through the real ``dynamixel_sdk``.

``driver`` has the lifecycle hooks; ``bus`` the blocking bus operations (retries, diagnosis,
the Bus Watchdog); ``tables`` the control table as data; ``units`` tick/radian conversions with
calibration; ``settings`` the manifest table (with the Bus Watchdog's units); ``messages`` the
wording of errors; ``port`` and ``sync_read`` the two SDK classes adapted (timing and waiting,
and the status error byte); ``_sdk`` the typed view of the SDK parts used.
"""
