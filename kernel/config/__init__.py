"""The core's configuration builder: a scenario's or a manifest's sections → CoreConfig.

:mod:`kernel.config.build` reads ``robot``, ``timing``, ``phases``, ``session``, ``allowlist``,
``motion`` and ``envelope`` (with :mod:`kernel.config.kinematics`, :mod:`kernel.config.session`,
:mod:`kernel.config.envelope` and the one workspace box of :mod:`kernel.config.workspace`) for
all three of its callers: the scenario loader (:mod:`kernel.scenario.load`), the manifest loader
(:mod:`kernel.manifest`) and the job worker process (:mod:`kernel.shell.worker`), and replay
through the scenario loader. The leaf readers it shares with the scenario files and the safety
monitor's view stay in :mod:`kernel.scenario` (``fields``, ``bounds``, ``document``). This
package imports nothing itself, so the monitor's view can read a leaf without the builder.
"""
