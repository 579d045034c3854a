"""What differs between the emulated PX4 and ArduPilot Copter: modes and their encodings, parameters, stream rates.

Sources: ``shared/docs/mavlink-facts.md`` (PX4 ``px4_custom_mode.h``, ``mavlink_main.cpp`` onboard rates,
``commander_params.c``; ArduPilot ``ArduCopter/mode.h`` numbers, ``Parameters.cpp``, ``GCS_Common.cpp``).
Parameter values are SI unless the real autopilot uses other units (ArduPilot's cm and cm/s are kept, so a
ground station shows the numbers it would show on a real vehicle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from estimators.model.vehicle import Vehicle
from sim_bridge.inner.airframe import default_rate_gains
from sim_bridge.inner.px4_hover_thrust import HTE_DEFAULTS as HTE

# MAV_MODE_FLAG bits
CUSTOM = 1
TEST = 2
AUTO = 4
GUIDED = 8
STABILIZE = 16
HIL = 32
MANUAL_INPUT = 64
SAFETY_ARMED = 128

# MAV_PARAM_TYPE
INT8 = 2
INT16 = 4
INT32 = 6
REAL32 = 9


@dataclass(frozen=True)
class Mode:
    """One flight mode: its wire encoding, what the emulator does in it, and whether arming is allowed."""

    name: str
    custom_mode: int  # HEARTBEAT.custom_mode
    kind: str  # offboard | guided | hold | althold | stabilized | acro | takeoff | land | rtl
    base_flags: int  # MAV_MODE_FLAG bits other than SAFETY_ARMED
    armable: bool = True


def px4_custom(main: int, sub: int = 0) -> int:
    """PX4 ``custom_mode`` = main << 16 | sub << 24 (``union px4_custom_mode``)."""
    return (main << 16) | (sub << 24)


_PX4_MANUAL = CUSTOM | MANUAL_INPUT
_PX4_ASSIST = CUSTOM | MANUAL_INPUT | STABILIZE
_PX4_AUTO = CUSTOM | AUTO | GUIDED | STABILIZE

PX4_MODES: list[Mode] = [
    Mode("MANUAL", px4_custom(1), "stabilized", _PX4_MANUAL),
    Mode("ALTCTL", px4_custom(2), "althold", _PX4_ASSIST),
    Mode("POSCTL", px4_custom(3), "hold", _PX4_ASSIST | GUIDED),
    Mode("AUTO.TAKEOFF", px4_custom(4, 2), "takeoff", _PX4_AUTO),
    Mode("AUTO.LOITER", px4_custom(4, 3), "hold", _PX4_AUTO),
    Mode("AUTO.RTL", px4_custom(4, 5), "rtl", _PX4_AUTO, armable=False),
    Mode("AUTO.LAND", px4_custom(4, 6), "land", _PX4_AUTO, armable=False),
    Mode("ACRO", px4_custom(5), "acro", _PX4_MANUAL),
    Mode("OFFBOARD", px4_custom(6), "offboard", _PX4_AUTO),
    Mode("STABILIZED", px4_custom(7), "stabilized", _PX4_ASSIST),
]

_AP = CUSTOM | MANUAL_INPUT | STABILIZE
AP_MODES: list[Mode] = [
    Mode("STABILIZE", 0, "stabilized", _AP),
    Mode("ACRO", 1, "acro", CUSTOM | MANUAL_INPUT),
    Mode("ALT_HOLD", 2, "althold", _AP),
    Mode("GUIDED", 4, "guided", _AP | GUIDED),
    Mode("LOITER", 5, "hold", _AP | GUIDED),
    Mode("RTL", 6, "rtl", _AP | GUIDED, armable=False),
    Mode("LAND", 9, "land", _AP, armable=False),
    Mode("POSHOLD", 16, "hold", _AP | GUIDED),
    Mode("BRAKE", 17, "hold", _AP | GUIDED, armable=False),
    Mode("GUIDED_NOGPS", 20, "guided", _AP | GUIDED),
]


@dataclass
class Param:
    """One parameter: value, MAV_PARAM_TYPE, range, read-only flag, one-line meaning with units."""

    value: float
    ptype: int
    lo: float
    hi: float
    readonly: bool = False
    doc: str = ""


#: Default stream rates (Hz) of the PX4 ``onboard`` MAVLink mode (mavlink_main.cpp) for the messages emulated,
#: plus the emulator's load-angle sensor (DEBUG_VECT "LOADANG"), which PX4 does not have (its DEBUG_VECT
#: stream defaults to 10 Hz; the emulator's sensor defaults to 50 Hz).
PX4_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 5.0,
    "EXTENDED_SYS_STATE": 5.0,
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "HIGHRES_IMU": 50.0,
    "GLOBAL_POSITION_INT": 50.0,
    "LOCAL_POSITION_NED": 30.0,
    "ODOMETRY": 30.0,
    "ATTITUDE_TARGET": 10.0,
    "VFR_HUD": 10.0,
    "DEBUG_VECT": 50.0,
    "SYSTEM_TIME": 1.0,
    "HOME_POSITION": 0.5,
    "ESTIMATOR_STATUS": 1.0,  # sent only with an estimate error model (--ekf): the truth has no accuracy to report
    "SCALED_IMU": 0.0,
    "RAW_IMU": 0.0,
}

#: ArduPilot Copter: stream groups (SR0_* parameters, Hz) -> messages. Defaults are 4 Hz (what MAVProxy asks
#: for), SYS_STATUS 2 Hz; everything else only on SET_MESSAGE_INTERVAL.
AP_GROUPS: dict[str, list[str]] = {
    "SR0_RAW_SENS": ["RAW_IMU", "SCALED_IMU"],
    "SR0_EXT_STAT": ["SYS_STATUS"],
    "SR0_POSITION": ["GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"],
    "SR0_EXTRA1": ["ATTITUDE"],
    "SR0_EXTRA2": ["VFR_HUD"],
    "SR0_EXTRA3": ["SYSTEM_TIME"],
}
AP_GROUP_DEFAULTS = {
    "SR0_RAW_SENS": 4,
    "SR0_EXT_STAT": 2,
    "SR0_POSITION": 4,
    "SR0_EXTRA1": 4,
    "SR0_EXTRA2": 4,
    "SR0_EXTRA3": 1,
}
AP_RATES: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 2.0,
    "EXTENDED_SYS_STATE": 0.0,
    "ATTITUDE": 4.0,
    "ATTITUDE_QUATERNION": 0.0,
    "HIGHRES_IMU": 0.0,
    "GLOBAL_POSITION_INT": 4.0,
    "LOCAL_POSITION_NED": 4.0,
    "ODOMETRY": 0.0,
    "ATTITUDE_TARGET": 0.0,
    "VFR_HUD": 4.0,
    "DEBUG_VECT": 50.0,
    "SYSTEM_TIME": 1.0,
    "HOME_POSITION": 0.0,
    "ESTIMATOR_STATUS": 0.0,
    "SCALED_IMU": 4.0,
    "RAW_IMU": 4.0,
}


def _vehicle_params(v: Vehicle) -> dict[str, Param]:
    """Read-only vehicle constants (both flavours): what the emulator's plant is made of, SI."""
    ix, iy, iz = v.inertia
    return {
        "EMU_MASS": Param(v.mass_vehicle, REAL32, 0, 1e3, True, "vehicle mass M, kg"),
        "EMU_LOAD_MASS": Param(v.mass_load, REAL32, 0, 1e3, True, "load mass m, kg"),
        "EMU_CABLE_LEN": Param(v.cable_length, REAL32, 0, 1e3, True, "cable length l, m"),
        "EMU_IXX": Param(ix, REAL32, 0, 1e3, True, "roll inertia, kg m^2"),
        "EMU_IYY": Param(iy, REAL32, 0, 1e3, True, "pitch inertia, kg m^2"),
        "EMU_IZZ": Param(iz, REAL32, 0, 1e3, True, "yaw inertia, kg m^2"),
        "EMU_ARM_LEN": Param(v.arm_length, REAL32, 0, 1e3, True, "arm length, m"),
        "EMU_MOT_TMAX": Param(v.motor_thrust_max, REAL32, 0, 1e3, True, "max thrust of one motor, N"),
        "EMU_THR_MAX": Param(v.thrust_max, REAL32, 0, 1e4, True, "max collective thrust (normalized 1.0), N"),
        "EMU_MOT_TAU": Param(v.motor_time_constant, REAL32, 0, 10, True, "motor time constant, s"),
        "EMU_YAW_COEF": Param(v.yaw_moment_coefficient, REAL32, 0, 10, True, "yaw moment coefficient, m"),
        "EMU_GRAVITY": Param(v.gravity, REAL32, 0, 100, True, "gravity, m/s^2"),
    }


#: PX4's stock rate gains (mc_rate_control defaults) are tuned for SIH's vehicle: 1.0 kg, Ixx = Iyy 0.025,
#: Izz 0.030 kg m^2, 5 N rotors at 0.2 m x 0.2 m (centre-to-motor 0.2 sqrt 2 m), reaction torque 0.02 N m / N.
_SIH_UNIT_TORQUE = (2.0 * 5.0 * 0.2 * math.sqrt(2.0), 4.0 * 5.0 * 0.02)  # the allocator's unit roll, yaw torque, N m
_SIH_INERTIA = (0.025, 0.030)
_PX4_RATE = {  # P, I, D, integrator limit (roll = pitch, yaw)
    "ROLL": (0.15, 0.2, 0.003, 0.3),
    "PITCH": (0.15, 0.2, 0.003, 0.3),
    "YAW": (0.2, 0.1, 0.0, 0.3),
}


def px4_gain_scale(v: Vehicle) -> tuple[float, float]:
    """Factor on PX4's stock rate gains (roll / pitch, yaw) that gives vehicle ``v`` SIH's closed-loop rate
    dynamics: the gains are normalized torque per rad/s, so they scale with inertia / allocator unit torque
    (rotors at +-1 normalized: unit roll torque 2 f_max d on an X, sqrt(2) f_max d on a "+", unit yaw torque
    4 f_max c). 1.0 for SIH's."""
    # a unit roll command moves each motor off the roll axis by 1/sqrt(2): 4 of them on an X, 2 on a "+"
    unit_rp = (4.0 if v.frame == "x" else 2.0) * v.motor_thrust_max * v.moment_arm / math.sqrt(2.0)
    unit_y = 4.0 * v.motor_thrust_max * v.yaw_moment_coefficient
    k_rp = (v.inertia[0] / unit_rp) / (_SIH_INERTIA[0] / _SIH_UNIT_TORQUE[0])
    k_y = (v.inertia[2] / unit_y) / (_SIH_INERTIA[1] / _SIH_UNIT_TORQUE[1])
    return k_rp, k_y


def _px4_rate_params(v: Vehicle) -> dict[str, Param]:
    k_rp, k_y = px4_gain_scale(v)
    out: dict[str, Param] = {}
    for axis, (p, i, d, lim) in _PX4_RATE.items():
        k = k_y if axis == "YAW" else k_rp
        short = {"ROLL": "RR", "PITCH": "PR", "YAW": "YR"}[axis]
        name = axis.lower()
        out[f"MC_{axis}RATE_P"] = Param(round(p * k, 5), REAL32, 0.0, 50.0, doc=f"{name} rate P, norm. torque/(rad/s)")
        out[f"MC_{axis}RATE_I"] = Param(round(i * k, 5), REAL32, 0.0, 500.0, doc=f"{name} rate I, norm. torque/rad")
        out[f"MC_{axis}RATE_D"] = Param(round(d * k, 6), REAL32, 0.0, 5.0, doc=f"{name} rate D, norm. torque/(rad/s^2)")
        out[f"MC_{axis}RATE_FF"] = Param(0.0, REAL32, 0.0, 50.0, doc=f"{name} rate feed-forward")
        out[f"MC_{axis}RATE_K"] = Param(1.0, REAL32, 0.01, 5.0, doc=f"{name} rate controller gain factor")
        out[f"MC_{short}_INT_LIM"] = Param(lim, REAL32, 0.0, 10.0, doc=f"{name} rate integrator limit, norm. torque")
    return out


def _px4_rotor_params(v: Vehicle) -> dict[str, Param]:
    """CA_ROTORn_PX / PY / KM / CT of the vehicle's frame: SIH's quadrotor X numbering (airframe 10040) or a "+",
    normalized positions +-1 as SIH's."""
    from sim_bridge.inner.px4_inner import quad_rotors

    out: dict[str, Param] = {}
    for n, r in enumerate(quad_rotors(v.frame)):
        out[f"CA_ROTOR{n}_PX"] = Param(r.px, REAL32, -100.0, 100.0, doc=f"rotor {n} position x (forward)")
        out[f"CA_ROTOR{n}_PY"] = Param(r.py, REAL32, -100.0, 100.0, doc=f"rotor {n} position y (right)")
        out[f"CA_ROTOR{n}_KM"] = Param(r.km, REAL32, -1.0, 1.0, doc=f"rotor {n} moment coefficient (spin sign)")
        out[f"CA_ROTOR{n}_CT"] = Param(r.ct, REAL32, 0.0, 100.0, doc=f"rotor {n} thrust coefficient")
    return out


def px4_params(v: Vehicle) -> dict[str, Param]:
    """PX4 parameters the emulator implements (names, defaults and ranges as in PX4; gains tuned to ``v``)."""
    # the vehicle file's hover throttle when it states one (px4-sih: PX4's 0.5, physically 0.49), else the physics
    hover = v.hover_throttle if v.hover_throttle is not None else round(v.hover_thrust_normalized, 4)
    p: dict[str, Param] = {
        "COM_OF_LOSS_T": Param(1.0, REAL32, 0.0, 60.0, doc="offboard setpoint loss timeout, s"),
        "COM_OBL_RC_ACT": Param(
            0,
            INT32,
            0,
            7,
            doc="offboard loss action: 0 Position 1 Altitude 2 Stabilized 3 Return 4 Land 5 Hold 6 Terminate 7 Disarm",
        ),
        "MPC_THR_HOVER": Param(hover, REAL32, 0.1, 0.8, doc="hover thrust, normalized 0..1 of max thrust"),
        "MPC_USE_HTE": Param(1, INT32, 0, 1, doc="1: position control flies the hover thrust estimator's estimate"),
        "HTE_HT_NOISE": Param(HTE["HTE_HT_NOISE"], REAL32, 0.0001, 1.0, doc="hover thrust process noise, normalized/s"),
        "HTE_ACC_GATE": Param(HTE["HTE_ACC_GATE"], REAL32, 1.0, 10.0, doc="acceleration innovation gate, SD"),
        "HTE_HT_ERR_INIT": Param(HTE["HTE_HT_ERR_INIT"], REAL32, 0.0, 1.0, doc="initial hover thrust uncertainty"),
        "HTE_VXY_THR": Param(HTE["HTE_VXY_THR"], REAL32, 1.0, 20.0, doc="horizontal speed above which noise grows"),
        "HTE_VZ_THR": Param(HTE["HTE_VZ_THR"], REAL32, 1.0, 10.0, doc="vertical speed above which the noise grows"),
        "HTE_THR_RANGE": Param(HTE["HTE_THR_RANGE"], REAL32, 0.01, 0.4, doc="estimate's range around MPC_THR_HOVER"),
        "MIS_TAKEOFF_ALT": Param(2.5, REAL32, 0.0, 80.0, doc="take-off altitude above home, m"),
        "MPC_TKO_SPEED": Param(1.5, REAL32, 1.0, 5.0, doc="take-off climb rate, m/s"),
        "MPC_LAND_SPEED": Param(0.7, REAL32, 0.6, 3.0, doc="landing descent rate, m/s"),
        "MPC_Z_VEL_MAX_UP": Param(3.0, REAL32, 0.5, 8.0, doc="max climb rate, m/s"),
        "MPC_Z_VEL_MAX_DN": Param(1.5, REAL32, 0.5, 4.0, doc="max descent rate, m/s"),
        "MPC_XY_CRUISE": Param(5.0, REAL32, 3.0, 20.0, doc="max horizontal speed in auto modes, m/s"),
        "MPC_XY_P": Param(0.95, REAL32, 0.0, 2.0, doc="horizontal position gain, 1/s"),
        "MPC_Z_P": Param(1.0, REAL32, 0.1, 1.5, doc="vertical position gain, 1/s"),
        "MPC_XY_VEL_P_ACC": Param(1.8, REAL32, 1.2, 5.0, doc="horizontal velocity gain, 1/s"),
        "MPC_XY_VEL_I_ACC": Param(0.4, REAL32, 0.0, 60.0, doc="horizontal velocity integral gain, 1/s^2"),
        "MPC_Z_VEL_P_ACC": Param(4.0, REAL32, 2.0, 15.0, doc="vertical velocity gain, 1/s"),
        "MPC_Z_VEL_I_ACC": Param(2.0, REAL32, 0.2, 3.0, doc="vertical velocity integral gain, 1/s^2"),
        "MPC_TILTMAX_AIR": Param(45.0, REAL32, 20.0, 89.0, doc="max tilt in position control, deg"),
        "RTL_RETURN_ALT": Param(60.0, REAL32, 0.0, 150.0, doc="return altitude above home, m"),
        "COM_DISARM_LAND": Param(2.0, REAL32, -1.0, 20.0, doc="auto-disarm after landing, s (<0 off)"),
        "COM_DISARM_PRFLT": Param(10.0, REAL32, -1.0, 20.0, doc="auto-disarm if no take-off after arming, s"),
        "MC_ROLL_P": Param(4.0, REAL32, 0.0, 12.0, doc="roll attitude gain, 1/s"),
        "MC_PITCH_P": Param(4.0, REAL32, 0.0, 12.0, doc="pitch attitude gain, 1/s"),
        "MC_YAW_P": Param(2.8, REAL32, 0.0, 5.0, doc="yaw attitude gain, 1/s"),
        "MC_YAW_WEIGHT": Param(0.4, REAL32, 0.0, 1.0, doc="yaw weight of the attitude error, 0..1"),
        **_px4_rate_params(v),
        "MC_ROLLRATE_MAX": Param(220.0, REAL32, 0.0, 1800.0, doc="max roll rate, deg/s"),
        "MC_PITCHRATE_MAX": Param(220.0, REAL32, 0.0, 1800.0, doc="max pitch rate, deg/s"),
        "MC_YAWRATE_MAX": Param(200.0, REAL32, 0.0, 1800.0, doc="max yaw rate, deg/s"),
        "MC_AIRMODE": Param(0, INT32, 0, 2, doc="airmode: 0 off, 1 roll/pitch, 2 roll/pitch/yaw"),
        "IMU_GYRO_CUTOFF": Param(40.0, REAL32, 0.0, 1000.0, doc="gyro low-pass cutoff, Hz"),
        "IMU_DGYRO_CUTOFF": Param(20.0, REAL32, 0.0, 1000.0, doc="low-pass cutoff of the gyro derivative (D term), Hz"),
        "CA_ROTOR_COUNT": Param(4, INT32, 0, 12, True, "number of rotors"),
        **_px4_rotor_params(v),
        "MAV_SYS_ID": Param(1, INT32, 1, 250, True, "system id (fixed by the emulator's command line)"),
        "MAV_TYPE": Param(2, INT32, 0, 30, True, "MAV_TYPE_QUADROTOR"),
        "SYS_AUTOSTART": Param(4001, INT32, 0, 9999999, True, "airframe: generic quadrotor x"),
    }
    p.update(_vehicle_params(v))
    return p


def ap_params(v: Vehicle) -> dict[str, Param]:
    """ArduPilot Copter parameters the emulator implements (names, defaults, units as in ArduPilot 4.6)."""
    g = default_rate_gains(v)
    # the value saved from earlier flights: the vehicle file's hover throttle when it gives one, else the true one;
    # learned in flight from there (a stale saved value, e.g. a bare vehicle's, is the file's to state)
    hover = v.hover_throttle if v.hover_throttle is not None else round(v.hover_thrust_normalized, 4)
    p: dict[str, Param] = {
        "GUID_TIMEOUT": Param(3.0, REAL32, 0.1, 5.0, doc="guided attitude/velocity target timeout, s"),
        "GUID_OPTIONS": Param(0, INT32, 0, 255, doc="bitmask; bit 3 (8): SET_ATTITUDE_TARGET thrust is throttle"),
        "ATC_ANGLE_BOOST": Param(1, INT8, 0, 1, doc="1: throttle / cos(tilt) angle boost"),
        "MOT_THST_HOVER": Param(hover, REAL32, 0.125, 0.6875, doc="hover throttle, 0..1, learned in flight"),
        "MOT_HOVER_LEARN": Param(2, INT8, 0, 2, doc="hover throttle learning: 2 = learn and save, 0 = off"),
        "MOT_THST_EXPO": Param(0.65, REAL32, -1.0, 1.0, doc="thrust curve expo (thrust (1-e)u + e u^2 of actuator u)"),
        "PILOT_SPEED_UP": Param(250.0, REAL32, 50.0, 500.0, doc="pilot climb rate at full stick, cm/s"),
        "PILOT_SPEED_DN": Param(
            0.0, REAL32, 0.0, 500.0, doc="pilot descent rate at low stick, cm/s (0: PILOT_SPEED_UP)"
        ),
        "THR_DZ": Param(100.0, REAL32, 0.0, 300.0, doc="throttle stick deadzone around mid, PWM us"),
        "WPNAV_SPEED_UP": Param(250.0, REAL32, 10.0, 1000.0, doc="max climb rate in guided, cm/s"),
        "WPNAV_SPEED_DN": Param(150.0, REAL32, 10.0, 500.0, doc="max descent rate in guided, cm/s"),
        "WPNAV_SPEED": Param(1000.0, REAL32, 20.0, 2000.0, doc="horizontal speed, cm/s"),
        "PILOT_TKOFF_ALT": Param(0.0, REAL32, 0.0, 1000.0, doc="take-off altitude, cm"),
        "LAND_SPEED": Param(50.0, REAL32, 30.0, 200.0, doc="final landing descent rate, cm/s"),
        "RTL_ALT": Param(1500.0, REAL32, 200.0, 300000.0, doc="return altitude above home, cm"),
        "DISARM_DELAY": Param(10, INT8, 0, 127, doc="auto-disarm delay on the ground, s (0 off)"),
        "ANGLE_MAX": Param(3000.0, REAL32, 1000.0, 8000.0, doc="max lean angle, cdeg"),
        "ATC_ANG_RLL_P": Param(4.5, REAL32, 3.0, 12.0, doc="roll angle P, 1/s"),
        "ATC_ANG_PIT_P": Param(4.5, REAL32, 3.0, 12.0, doc="pitch angle P, 1/s"),
        "ATC_ANG_YAW_P": Param(4.5, REAL32, 3.0, 12.0, doc="yaw angle P, 1/s"),
        "ATC_RAT_RLL_P": Param(round(g.p[0], 4), REAL32, 0.0, 50.0, doc="roll rate P, normalized torque/(rad/s)"),
        "ATC_RAT_PIT_P": Param(round(g.p[1], 4), REAL32, 0.0, 50.0, doc="pitch rate P, normalized torque/(rad/s)"),
        "ATC_RAT_YAW_P": Param(round(g.p[2], 4), REAL32, 0.0, 50.0, doc="yaw rate P, normalized torque/(rad/s)"),
        "ATC_RAT_RLL_I": Param(round(g.i[0], 4), REAL32, 0.0, 500.0, doc="roll rate I, normalized torque/rad"),
        "ATC_RAT_PIT_I": Param(round(g.i[1], 4), REAL32, 0.0, 500.0, doc="pitch rate I, normalized torque/rad"),
        "ATC_RAT_YAW_I": Param(round(g.i[2], 4), REAL32, 0.0, 500.0, doc="yaw rate I, normalized torque/rad"),
        "PSC_POSXY_P": Param(1.0, REAL32, 0.5, 2.0, doc="horizontal position P, 1/s"),
        "PSC_POSZ_P": Param(1.0, REAL32, 1.0, 3.0, doc="vertical position P, 1/s"),
        "PSC_VELXY_P": Param(2.0, REAL32, 0.1, 6.0, doc="horizontal velocity P, 1/s"),
        "PSC_VELZ_P": Param(5.0, REAL32, 1.0, 8.0, doc="vertical velocity P, 1/s"),
        "SYSID_THISMAV": Param(1, INT16, 1, 255, True, "system id (fixed by the emulator's command line)"),
        "FRAME_CLASS": Param(1, INT8, 0, 15, True, "1 = quad"),
        "FRAME_TYPE": Param(1, INT8, 0, 18, True, "1 = X"),
    }
    for name, hz in AP_GROUP_DEFAULTS.items():
        p[name] = Param(hz, INT16, 0, 50, doc="stream group rate, Hz (" + ", ".join(AP_GROUPS[name]) + ")")
    p.update(_vehicle_params(v))
    return p


@dataclass
class Flavor:
    """Everything flavour-specific the autopilot needs."""

    name: str
    autopilot_type: int  # MAV_AUTOPILOT
    modes: list[Mode]
    boot_mode: str
    params: dict[str, Param]
    rates: dict[str, float]
    capabilities: int
    version: int  # flight_sw_version (major << 24 | minor << 16 | patch << 8 | type)
    dialect: str
    by_name: dict[str, Mode] = field(default_factory=dict)
    by_custom: dict[int, Mode] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.by_name = {m.name: m for m in self.modes}
        self.by_custom = {m.custom_mode: m for m in self.modes}

    @property
    def is_px4(self) -> bool:
        """True for the PX4 flavour."""
        return self.name == "px4"


#: MAV_PROTOCOL_CAPABILITY bits both flavours claim: PARAM_FLOAT 2, COMMAND_INT 8, SET_ATTITUDE_TARGET 64,
#: SET_POSITION_TARGET_LOCAL_NED 128, MAVLINK2 8192. PX4 adds PARAM_ENCODE_BYTEWISE 16, ArduPilot
#: PARAM_ENCODE_C_CAST 131072 (how integer parameters travel in PARAM_VALUE's float field).
_CAP_COMMON = 2 | 8 | 64 | 128 | 8192


def make_flavor(name: str, vehicle: Vehicle) -> Flavor:
    """The PX4 (``"px4"``) or ArduPilot Copter (``"ardupilot"``) flavour for a vehicle."""
    if name == "px4":
        return Flavor(
            "px4",
            12,
            PX4_MODES,
            "AUTO.LOITER",
            px4_params(vehicle),
            dict(PX4_RATES),
            _CAP_COMMON | 16,
            (1 << 24) | (16 << 16) | (0 << 8) | 255,
            "common",
        )
    if name == "ardupilot":
        return Flavor(
            "ardupilot",
            3,
            AP_MODES,
            "STABILIZE",
            ap_params(vehicle),
            dict(AP_RATES),
            _CAP_COMMON | 131072,
            (4 << 24) | (6 << 16) | (0 << 8) | 255,
            "ardupilotmega",
        )
    raise ValueError(f"unknown flavour {name!r}")


def deg(x: float) -> float:
    """Degrees -> radians (parameters in degrees are converted where they are used)."""
    return math.radians(x)
