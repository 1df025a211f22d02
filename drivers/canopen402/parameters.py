"""The parameter and PDO setup of every drive at configure: blocking SDO, device thread only.

Joints get their cycle, quick-stop option and the manifest's limits in counts
(:func:`drivers.canopen402.bringup.write_parameters`), the gripper drive its own
(:func:`drivers.canopen402.gripper.configure`); then every drive its PDO layout.
"""

from __future__ import annotations

from collections.abc import Sequence

from drivers.base import ControlConfig, DriverInitError
from drivers.canopen402 import bringup, gripper
from drivers.canopen402.link import Link
from drivers.canopen402.settings import CiA402Settings
from drivers.canopen402.units import JointScale


def configure_drives(link: Link, settings: CiA402Settings, scales: Sequence[JointScale],
                     control: ControlConfig) -> tuple[int, ...]:
    """Returns every joint's motor rated torque (0x6076, mN·m).

    Raises:
        DriverInitError: a limit that does not fit the drive's INTEGER32 counts.
    """
    rated = []
    for joint, node in enumerate(link.joints):
        try:
            rated.append(bringup.write_parameters(node, scales[joint], control, joint))
        except ValueError as error:
            raise DriverInitError(settings.name, f"joint {joint} (node {node.id}): {error}; "
                                  "check counts_per_rev and the joint limits") from error
    if link.gripper is not None:
        gripper.configure(link.gripper, settings.gripper_scale(), control)
    for node in link.nodes:
        bringup.map_pdos(node)
        bringup.stop_echo(link.network, node)
    return tuple(rated)
