"""The FMU adapter base shared by the IMU paper's two filters, ComplementaryFilter and ImuEkf
(IMU paper, section 4): the planar kinematic pose and the IMU readings in, the tool pose out,
mapped between the planar FlexFusion conventions and the filters' 3-D frames
(:func:`fmus.common.frames.planar_pose`)."""
from __future__ import annotations

from fmus.common import quaternion as qt
from fmus.common.filter_adapter import FilterAdapter
from fmus.common.frames import G, planar_pose


class ImuPoseAdapter(FilterAdapter):
    """Inputs ``p_fk``, ``phi_fk``, ``acc_s``, ``gyro_s`` (and ``t_meas``), outputs the tool pose
    ``p_tool_hat``, ``phi_tool_hat``, ``p_hat``, ``q_hat``; no direct feedthrough. A subclass
    declares its other outputs after calling ``super().__init__``."""

    feedthrough = False

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.input("p_fk", 2, unit="m", description="forward-kinematics tool position, world x and z")
        self.input("phi_fk", unit="rad", description="forward-kinematics tool angle about world y")
        self.input("acc_s", 3, unit="m/s2", description="IMU specific force, sensor frame",
                   start=(0.0, 0.0, G))
        self.input("gyro_s", 3, unit="rad/s", description="IMU angular rate, sensor frame")
        self.declare_t_meas()
        self.output("p_tool_hat", 2, unit="m", description="estimated tool position, world x and z")
        self.output("phi_tool_hat", unit="rad", description="estimated tool angle about world y")
        self.output("p_hat", 3, unit="m", description="estimated tool position, world x, y, z")
        self.output("q_hat", 4, unit="1", description="estimated tool orientation, unit quaternion "
                    "(w, x, y, z), tool to world", start=(1.0, 0.0, 0.0, 0.0))

    def _pose(self):
        """The kinematic pose input in 3-D: position and orientation (tool to world)."""
        return planar_pose(self.p_fk, self.phi_fk)

    def _show_pose(self, mount, p_sensor, q_sensor) -> None:
        """Set the pose outputs from the sensor's estimated pose on its ``mount``."""
        p, q = mount.tool_pose(p_sensor, q_sensor)
        self.p_hat[:] = p
        self.p_tool_hat[0], self.p_tool_hat[1] = p[0], p[2]
        self.q_hat[:] = q
        self.phi_tool_hat = qt.angle_y(q)


__all__ = ["ImuPoseAdapter"]
