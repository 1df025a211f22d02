"""Programs that stand between warden and a policy server that does not speak warden's wire.

Each runs in its own small venv, apart from warden's and apart from the server's, and imports
only ``peer`` (warden's wire, the server's side) from this repository.
"""
