"""Machine description: feed axes, motor spindle and NC settings of one machine tool.

The one description every layer reads: the simulator runs it (:mod:`cnctwin.sim`), the
calibration writes it (``cnctwin calibrate``), the edge runtime, the dashboard and the fleet
jobs load it through :mod:`cnctwin.machine.file`. It lives below the analyses so that nothing
needs the simulator to know what a machine is.

:class:`FeedAxis` holds one feed axis' NC machine data (Kv MD32200, FFW mode MD32620, jerk
filter MD32402/MD32410, dynamic response adaptation MD32910, equivalent times MD32810/MD32800),
its SINAMICS speed-controller gains and its mechanics. :class:`SpindleMotor` is the motor
spindle (PMSM and its drive). :class:`Machine` groups five feed axes and the spindle with the
cycle times and the axis-number map. Descriptions round-trip through TOML
(:meth:`Machine.to_toml` / :meth:`Machine.from_toml`) and take dotted-path overrides
(:meth:`Machine.with_overrides`).

Kinds of default values: [S] sourced (Siemens manuals and datasheets, see docs/simulator.md),
[T] thesis, [D] derived, [E] engineering estimate.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w

from cnctwin.exceptions import ConfigError

__all__ = [
    "KV_UNIT_PER_S",
    "FeedAxis",
    "Machine",
    "SpindleMotor",
    "dynamic_response_adaptation_times",
]

KV_UNIT_PER_S = 1000.0 / 60.0
"""1 (m/min)/mm in 1/s (MD10230 SCALING_FACTORS_USER_DEF[9] = 16.666667)."""


@dataclass(frozen=True)
class SpindleMotor:
    """Motor spindle (PMSM) of the thesis machine and its SINAMICS drive.

    Defaults describe the 5-axis Spinner machining centre of the thesis (SINUMERIK 840D sl,
    S120 drive). Kinds: [T] thesis, [S] datasheet/manual (see docs/simulator.md and
    docs/reference/physics-and-performance.md §2), [D] derived, [E] engineering estimate.

    Attributes
    ----------
    pole_count : int
        Number of magnetic poles (pole pairs = pole_count / 2); sets the stator frequency
        f = N * poles / 120 (thesis Eq. 4.1). [E] 4
    max_speed_rpm : float
        Maximum speed [rpm]. [T] 20000 (catalog value quoted in thesis §3.2.2)
    base_speed_rpm : float
        Field-weakening start speed of the datasheet [rpm]. [T] 7000 (thesis §4.1). Used to
        document/check the voltage parameters; the simulated onset follows from the voltage
        ellipse (``dc_link_v``, ``modulation_max``, ``kt_nm_per_a``).
    kt_nm_per_a : float
        Torque constant per A rms of Iq at ``kt_ref_temperature_c`` magnet temperature [Nm/A].
        [T] 1.04 (thesis Eq. 4.3)
    kt_ref_temperature_c : float
        Magnet temperature at which ``kt_nm_per_a`` holds [degC]. [E] 20
    magnet_temp_coeff_per_k : float
        Relative change of the magnet flux (and Kt) per kelvin of rotor temperature [1/K].
        [S] NdFeB alpha(Br) -0.09 ... -0.12 %/K; default -0.0011
    kt_saturation_knee_a : float
        |Iq| (A rms) above which iron saturation lowers Kt [A]. [E] 24 (= rated current)
    kt_saturation_coeff : float
        Saturation strength: Kt factor 1 / (1 + c (|Iq|/knee - 1)^2) above the knee [-]. [E] 0.5
    viscous_friction_nm_per_rpm : float
        Viscous friction coefficient B at ``friction_ref_temperature_c`` [Nm/rpm].
        [T] 8.42e-5 (thesis Eq. 4.4)
    coulomb_friction_nm : float
        Coulomb friction torque tau_f at ``friction_ref_temperature_c`` [Nm]. [T] 0.35 (Eq. 4.4)
    friction_ref_temperature_c : float
        Bearing (rotor) temperature at which B and tau_f hold [degC]. [E] 22 (cold machine)
    viscous_friction_temp_coeff_per_k : float
        Relative change of B per kelvin of rotor/bearing temperature [1/K]; negative because
        the grease viscosity falls as it warms (the thesis sees the current fall while the
        motor warms at 5000 and 7000 rpm, Fig. 4.4). [E] -0.005
    coulomb_friction_temp_coeff_per_k : float
        Relative change of tau_f per kelvin [1/K]. [E] -0.002
    stribeck_torque_nm : float
        Extra breakaway/mixed-lubrication torque at standstill, decaying with speed [Nm];
        makes the mean current non-linear below ~1100 rpm (thesis §4.1). [E] 0.15
    stribeck_speed_rpm : float
        Stribeck decay speed [rpm]. [E] 400
    viscous_rolloff_speed_rpm : float
        Speed above which the viscous friction grows less than linearly (shear thinning and
        oil-film heating of the bearings) so that mean Iq departs from the straight line above
        ~5000 rpm (thesis Fig. 4.1) [rpm]. [E] 5000
    viscous_rolloff_ratio : float
        Slope of the viscous term above the knee relative to below it [-]. [E] 0.4
    viscous_rolloff_width_rpm : float
        Rounding width W of the knee: the viscous speed is
        N_eff = N - (1 - r) W softplus((N - N_k)/W) [rpm]. [E] 300
    friction_smoothing_rpm : float
        Speed band in which Coulomb friction changes sign (tanh) [rpm]. [E] 2
    stator_resistance_ohm : float
        Phase resistance Rs at 20 degC [Ohm]. [E] 0.12
    d_inductance_h : float
        d-axis inductance Ld [H]. [E] 0.006
    q_inductance_h : float
        q-axis inductance Lq [H] (Lq > Ld: interior magnets; reluctance torque with id < 0
        makes mean Iq fall in field weakening, thesis Fig. 3.8a). [E] 0.009
    dc_link_v : float
        DC-link voltage [V]. [S] ALM 600-720 V (docs/reference/physics-and-performance.md §2)
    modulation_max : float
        Maximum phase-voltage amplitude as a fraction of Vdc/sqrt(3) (space-vector modulation;
        > 1 = over-modulation) [-]. [E] 1.05, which puts the voltage limit of the no-load
        motor at ~7000 rpm with Kt = 1.04 Nm/A.
    current_limit_a : float
        Maximum current |I| [A rms]. [E] 48
    rated_current_a : float
        Rated (S1) current [A rms]. [E] 24
    rated_torque_nm : float
        Rated torque for LOAD % and torque utilisation [Nm]. [E] 25
    inertia_kg_m2 : float
        Rotor + spindle shaft + tool holder inertia J [kg m^2]. [E] 0.015 (motor spindles of
        this size: 0.01-0.03; J is not given in the thesis,
        docs/reference/physics-and-performance.md §4)
    current_loop_time_constant_s : float
        Equivalent first-order time constant of the closed current loop [s].
        [S] torque rise time 0.5-0.8 ms on S120 (docs/reference/physics-and-performance.md §1.3);
        0.0005
    speed_ctrl_kp_nm_s_per_rad : float
        Speed-controller proportional gain [Nm s/rad]. [E] 2.4 (~25 Hz with J = 0.015)
    speed_ctrl_ti_s : float
        Speed-controller integral time [s]. [E] 0.02
    position_ctrl_kv_per_s : float
        Spindle position-loop gain in rigid tapping (mode 1) [1/s]. [S] Kv <= 3 (m/min)/mm
        = 50 1/s for 840D sl spindles (docs/reference/physics-and-performance.md §1.2); 30
    spos_speed_rpm : float
        Largest speed of the move to the programmed angle when position control takes over
        (SPOS, rigid tapping) [rpm]. [S] MD35300 SPIND_POSCTRL_VELO, default 500
    spos_accel_rev_s2 : float
        Acceleration of that move [rev/s^2]. [S] MD35210 GEAR_STEP_POSCTRL_ACCEL, default 30
    ambient_temperature_c : float
        Ambient / coolant temperature [degC]. [E] 22
    stator_to_ambient_k_per_w : float
        Thermal resistance winding -> housing/coolant [K/W]. [E] 0.04
    rotor_to_stator_k_per_w : float
        Thermal resistance rotor/bearings -> stator [K/W]. [E] 0.06
    stator_heat_capacity_j_per_k : float
        Heat capacity of the stator node [J/K]. [E] 20000 (time constant ~13 min)
    rotor_heat_capacity_j_per_k : float
        Heat capacity of the rotor/bearing node [J/K]. [E] 9000 (time constant ~15 min)
    iron_loss_w_at_base : float
        Iron losses at ``base_speed_rpm`` [W], scaled with (f/f_base)^1.6. [E] 150
    copper_temp_coeff_per_k : float
        Relative change of Rs per kelvin (copper) [1/K]. [S] 0.0039
    ripple_amplitude_a : float
        Amplitude of the stator-frequency Iq ripple at f = N poles/120 [A]. [E] 0.08
        (thesis Fig. 4.3: visible but not moving the mean)
    ripple_high_speed_a : float
        Extra ripple amplitude reached at ``max_speed_rpm``, growing from
        ``ripple_growth_speed_rpm`` (thesis Fig. 3.8a: ripple increases after 16800 rpm) [A].
        [E] 0.6
    ripple_growth_speed_rpm : float
        Speed from which the ripple grows [rpm]. [T] 16800
    current_noise_a : float
        Standard deviation of the current measurement noise per 2 ms sample [A]. [E] 0.03
    speed_noise_rpm : float
        Standard deviation of the speed measurement noise [rpm]. [E] 0.5
    torque_noise_nm : float
        Standard deviation of random load torque (bearing/cogging noise) per 2 ms [Nm]. [E] 0.02
    lf_smoothing_time_s : float
        PT1 smoothing time constant of the LF drive values r0063/r0068/r0078 [s]. [S] 0.1
        (thesis §3.2.1: "100 ms smoothing time constant")
    flux_base_speed_rpm : float
        Speed above which the drive weakens the machine's flux as ``(n_b / n)^flux_exponent``
        [rpm], so that the torque per reported (torque-producing) current falls with speed:
        the constant-power range of an induction motor spindle (the KIT DMC 60H data: Kt x
        speed constant within +-5 % over 2400-4000 rpm, docs/real-data-kit.md). 0 = no such
        law (a permanent-magnet spindle: only the voltage-ellipse field weakening above
        ``base_speed_rpm``). [E] 0
    flux_exponent : float
        Exponent of that flux law [-]; 1 = constant power. [E] 1
    speed_setpoint_interpolation : bool
        In speed control the drive interpolates the speed setpoint linearly over the 2 ms
        cycle from the previous command to the new one (the isochronous setpoint channel of
        the S120: "DSC linear/spline" interpolates the speed pre-control to the speed
        controller's clock, function diagram 3090; drives in interpolated speed mode do the
        same). False: the setpoint steps once per cycle, the speed controller's proportional
        kick at every step of a ramp is over before the cycle's current is sampled, and the
        sampled current during a ramp reads ~3 % (J alpha) low. [S] True
    """

    pole_count: int = 4
    max_speed_rpm: float = 20000.0
    base_speed_rpm: float = 7000.0
    kt_nm_per_a: float = 1.04
    kt_ref_temperature_c: float = 20.0
    magnet_temp_coeff_per_k: float = -0.0011
    kt_saturation_knee_a: float = 24.0
    kt_saturation_coeff: float = 0.5
    viscous_friction_nm_per_rpm: float = 8.42e-5
    coulomb_friction_nm: float = 0.35
    friction_ref_temperature_c: float = 22.0
    viscous_friction_temp_coeff_per_k: float = -0.005
    coulomb_friction_temp_coeff_per_k: float = -0.002
    stribeck_torque_nm: float = 0.15
    stribeck_speed_rpm: float = 400.0
    viscous_rolloff_speed_rpm: float = 5000.0
    viscous_rolloff_ratio: float = 0.4
    viscous_rolloff_width_rpm: float = 300.0
    friction_smoothing_rpm: float = 2.0
    stator_resistance_ohm: float = 0.12
    d_inductance_h: float = 0.006
    q_inductance_h: float = 0.009
    dc_link_v: float = 600.0
    modulation_max: float = 1.05
    current_limit_a: float = 48.0
    rated_current_a: float = 24.0
    rated_torque_nm: float = 25.0
    inertia_kg_m2: float = 0.015
    current_loop_time_constant_s: float = 0.0005
    speed_ctrl_kp_nm_s_per_rad: float = 2.4
    speed_ctrl_ti_s: float = 0.02
    position_ctrl_kv_per_s: float = 30.0
    spos_speed_rpm: float = 500.0
    spos_accel_rev_s2: float = 30.0
    ambient_temperature_c: float = 22.0
    stator_to_ambient_k_per_w: float = 0.04
    rotor_to_stator_k_per_w: float = 0.06
    stator_heat_capacity_j_per_k: float = 20000.0
    rotor_heat_capacity_j_per_k: float = 9000.0
    iron_loss_w_at_base: float = 150.0
    copper_temp_coeff_per_k: float = 0.0039
    ripple_amplitude_a: float = 0.08
    ripple_high_speed_a: float = 0.6
    ripple_growth_speed_rpm: float = 16800.0
    current_noise_a: float = 0.03
    speed_noise_rpm: float = 0.5
    torque_noise_nm: float = 0.02
    lf_smoothing_time_s: float = 0.1
    flux_base_speed_rpm: float = 0.0
    flux_exponent: float = 1.0
    speed_setpoint_interpolation: bool = True

    @property
    def pole_pairs(self) -> int:
        """Pole pairs p = pole_count / 2."""
        return self.pole_count // 2

    @property
    def flux_linkage_vs(self) -> float:
        """Magnet flux linkage psi_pm (peak, amplitude-invariant dq) at the Kt reference [Vs].

        From Kt = 1.5 sqrt(2) p psi_pm with Kt per A rms.
        """
        return self.kt_nm_per_a / (1.5 * math.sqrt(2.0) * self.pole_pairs)

    @property
    def max_phase_voltage_v(self) -> float:
        """Largest phase-voltage amplitude the inverter can apply, m Vdc / sqrt(3) [V]."""
        return self.modulation_max * self.dc_link_v / math.sqrt(3.0)

    def stator_frequency_hz(self, speed_rpm: float) -> float:
        """Stator (electrical) frequency f = N poles / 120 [Hz] (thesis Eq. 4.1)."""
        return abs(speed_rpm) * self.pole_count / 120.0


@dataclass(frozen=True)
class FeedAxis:
    """One feed axis (linear: ball screw and slide; rotary: gear and table).

    Units of friction and speed parameters are per mm (linear) or per deg (rotary); forces are N
    on linear axes and load torques Nm on rotary axes.

    Attributes
    ----------
    name : str
        Machine axis name (``"X1"``).
    rotary : bool
        Rotary axis (positions in deg) instead of linear (mm).
    kv_m_min_per_mm : float
        Position-loop gain MD32200 [(m/min)/mm]. [S] 2.5 (802S example Z axis,
        docs/reference/physics-and-performance.md §1.2)
    ffw_mode : int
        MD32620 FFW_MODE: 0 none, 1 speed FFW + PT1 balancing, 2 torque FFW + PT1,
        3 speed FFW + dead-time balancing, 4 torque FFW + dead time. [E] 3
    ffw_weight : float
        MD32610 VELO_FFW_WEIGHT [-]. [S] normally 1
    jerk_filter_type : int
        MD32402 AX_JERK_MODE: 0 off, 1 2nd-order, 2 moving average, 4 double moving average.
        [E] 2
    jerk_time_s : float
        MD32410 AX_JERK_TIME [s]; the filter is active only if it exceeds one cycle.
        [S] type 2: 1-16 cycles; default 0.008 (4 cycles)
    dyn_match_time_s : float
        MD32910 DYN_MATCH_TIME [s]: extra delay to match the slowest interpolating axis
        (:func:`dynamic_response_adaptation_times`). [S] definition; default 0
    equiv_speedctrl_time_s : float
        MD32810 EQUIV_SPEEDCTRL_TIME [s]: balancing time of speed FFW (mode 1/3) and the NC's
        lag model. [S] K3 examples 1-4 ms; default 0.002
    equiv_currctrl_time_s : float
        MD32800 EQUIV_CURRCTRL_TIME [s]: current-loop equivalent time; used as the drive's
        current-loop PT1 and as the balancing time of torque FFW (mode 2/4).
        [S] torque rise 0.5-0.7 ms (S120 1FK7/1FT7); default 0.0005
    speed_kp_nm_s_per_rad : float
        Speed-controller gain at the motor [Nm s/rad]. [E] ~600 rad/s crossover
    speed_ti_s : float
        Speed-controller integral time [s]. [E] 0.008
    motor_inertia_kgm2 : float
        Motor rotor + coupling + screw inertia [kg m^2]. [E] 1FK7-class 0.0015
    screw_pitch_mm : float
        Ball-screw lead [mm/rev] (linear axes). [E] 10
    mass_kg : float
        Moved mass of the slide incl. workpiece (linear axes) [kg]. [E]
    gear_ratio : float
        Motor revolutions per table revolution (rotary axes) [-]. [E] 100
    load_inertia_kgm2 : float
        Table/cradle inertia (rotary axes) [kg m^2]. [E]
    coulomb_n : float
        Coulomb friction at the slide [N] (rotary: at the table [Nm]). [E]
    viscous_n_per_mm_s : float
        Viscous friction [N/(mm/s)] (rotary: [Nm/(deg/s)]). [E]
    stribeck_n : float
        Extra breakaway friction at standstill [N] (rotary [Nm]). [E]
    stribeck_speed_mm_s : float
        Stribeck decay speed [mm/s] (rotary [deg/s]). [E] 1
    friction_smoothing_mm_s : float
        Speed band v_eps of the Coulomb sign change [mm/s] (rotary [deg/s]). Inside the band
        the friction acts as a damper c = (F_c + F_s) / v_eps; for a standing slide under a
        small oscillating force that damper stands in for the pre-sliding (micro-slip) regime
        of rolling guides and ball screws, which is spring-like up to micrometre displacements
        (Futami et al., J. JSPE 57(10) 1808, 1991: linear spring below ~0.1 um, full rolling
        only beyond ~100 um). Matching c omega to a pre-sliding stiffness (F_c + F_s) / x_ps
        gives v_eps = omega x_ps: 0.2 mm/s for x_ps = 0.8 um at 40 Hz (2400 rpm drilling).
        [D/E] 0.2 on linear axes (a 0.02 mm/s band made the standing slide a 1e7 N s/m damper
        that hid the lateral drilling forces, 10 nm at 20 N; 0.5 mm/s would shrink the
        quadrant glitch at a circle's reversal below 1 um)
    max_velocity_mm_min : float
        Maximum axis velocity MD32000 [mm/min] (rotary [deg/min]). [E]
    max_accel_mm_s2 : float
        Maximum acceleration MD32300 [mm/s^2] (rotary [deg/s^2]). [E]
    max_jerk_mm_s3 : float
        Maximum jerk MD32431 [mm/s^3] (rotary [deg/s^3]). [E]
    kt_nm_per_a : float
        Motor torque constant [Nm/A rms]. [E] 1FK7-class 1.4
    current_limit_a : float
        Current limit [A rms]. [E]
    rated_torque_nm : float
        Rated motor torque for LOAD % [Nm]. [E]
    encoder_resolution : float
        Encoder resolution at the load [mm] (rotary [deg]). [E] 1e-5 (10 nm)
    dsc : bool
        Dynamic servo control (position loop closed in the drive at 125 us). [S] 840D sl + S120
    dsc_spline : bool
        With DSC, the drive interpolates the NC's speed feedforward linearly over the
        position-control cycle (SINAMICS S120 "DSC with spline", p1191) instead of holding it:
        without it every 2 ms step of the feedforward during an acceleration kicks the speed
        loop, and the current sampled at the end of the cycle misses a third of the
        acceleration current (docs/simulator.md §1b). [S] S120 p1191; default on
    phase_resistance_ohm : float
        Winding resistance for copper losses in POWER and heating [Ohm]. [E] 0.8
    thermal_resistance_k_per_w : float
        Winding -> ambient thermal resistance [K/W]. [E] 0.4
    heat_capacity_j_per_k : float
        Motor heat capacity [J/K]. [E] 3000
    ambient_temperature_c : float
        Ambient temperature [degC]. [E] 22
    lf_smoothing_time_s : float
        PT1 smoothing of the LF drive values (r0063/r0068/r0078) [s]. [T] 0.1 (thesis §3.2.1)
    current_noise_a : float
        Std of the current measurement noise per 2 ms sample [A]; the drive's torque actual
        value (``TORQUE``) is Kt times the measured current and carries it too. [E] 0.05
        (real Capture4Analysis X1 at standstill: 0.027 A cycle to cycle, docs/simulator.md)
    encoder_noise : float
        Std of the white measurement noise of the NC's position measuring system per latch
        (2 ms) [mm] (rotary [deg]), before the encoder quantisation. It enters ``ENC_POS``,
        ``CTRL_DIFF2``, ``CONT_DEV`` and the NC's speed setpoint (``CMD_SPEED`` = Kv x the
        difference); the drive's 125 us speed loop uses its own (motor) encoder. [D] 1.5e-4
        (real Capture4Analysis X1 at standstill: ENC_POS steps of 0.28 um rms, white, and
        CMD_SPEED steps of Kv x that; docs/simulator.md)
    ripple_n : float
        Amplitude of a position-periodic force on the slide with the period of one motor
        revolution (ball-screw lead error and preload-torque fluctuation, cogging) [N]
        (rotary: [Nm] at the table). [E] 10 (JIS B 1192 allows +-30-40 % fluctuation of the
        preload torque of C3-C5 screws; 10 N is ~7 % of the 150 N friction)
    ripple_phase_rad : float
        Phase of that ripple at position 0 [rad], a property of the machine (the same in every
        recording of it; ``random_loop_overrides`` draws it for a hidden machine). [-] 0
    """

    name: str
    rotary: bool = False
    kv_m_min_per_mm: float = 2.5
    ffw_mode: int = 3
    ffw_weight: float = 1.0
    jerk_filter_type: int = 2
    jerk_time_s: float = 0.008
    dyn_match_time_s: float = 0.0
    equiv_speedctrl_time_s: float = 0.002
    equiv_currctrl_time_s: float = 0.0005
    speed_kp_nm_s_per_rad: float = 1.5
    speed_ti_s: float = 0.008
    motor_inertia_kgm2: float = 0.0015
    screw_pitch_mm: float = 10.0
    mass_kg: float = 400.0
    gear_ratio: float = 100.0
    load_inertia_kgm2: float = 0.0
    coulomb_n: float = 150.0
    viscous_n_per_mm_s: float = 0.2
    stribeck_n: float = 60.0
    stribeck_speed_mm_s: float = 1.0
    friction_smoothing_mm_s: float = 0.2
    max_velocity_mm_min: float = 30000.0
    max_accel_mm_s2: float = 3000.0
    max_jerk_mm_s3: float = 50000.0
    kt_nm_per_a: float = 1.4
    current_limit_a: float = 30.0
    rated_torque_nm: float = 10.0
    encoder_resolution: float = 1e-5
    dsc: bool = True
    dsc_spline: bool = True
    phase_resistance_ohm: float = 0.8
    thermal_resistance_k_per_w: float = 0.4
    heat_capacity_j_per_k: float = 3000.0
    ambient_temperature_c: float = 22.0
    lf_smoothing_time_s: float = 0.1
    current_noise_a: float = 0.05
    encoder_noise: float = 1.5e-4
    ripple_n: float = 10.0
    ripple_phase_rad: float = 0.0

    # ------------------------------------------------------------ derived quantities
    @property
    def kv_per_s(self) -> float:
        """Position-loop gain in 1/s: 16.667 x MD32200 [1/s]."""
        return self.kv_m_min_per_mm * KV_UNIT_PER_S

    @property
    def load_per_motor_rad(self) -> float:
        """Load travel per motor radian: pitch / 2 pi [mm/rad] or (180/pi) / i [deg/rad]."""
        if self.rotary:
            return (180.0 / math.pi) / self.gear_ratio
        return self.screw_pitch_mm / (2.0 * math.pi)

    @property
    def motor_torque_per_load_force(self) -> float:
        """Motor torque per unit load force: pitch[m] / 2 pi [Nm/N] or 1 / i [Nm/Nm]."""
        if self.rotary:
            return 1.0 / self.gear_ratio
        return self.screw_pitch_mm / 1000.0 / (2.0 * math.pi)

    @property
    def total_inertia_kgm2(self) -> float:
        """Inertia at the motor shaft: J_m + m (pitch/2pi)^2 or J_m + J_load / i^2 [kg m^2]."""
        if self.rotary:
            return self.motor_inertia_kgm2 + self.load_inertia_kgm2 / self.gear_ratio**2
        r = self.screw_pitch_mm / 1000.0 / (2.0 * math.pi)
        return self.motor_inertia_kgm2 + self.mass_kg * r * r

    @property
    def position_equivalent_time_s(self) -> float:
        """Equivalent time of the closed position loop the NC assumes [s].

        1/Kv without FFW, MD32810 with speed FFW (mode 1/3), MD32800 with torque FFW (2/4).
        """
        if self.ffw_mode == 0:
            return 1.0 / self.kv_per_s
        if self.ffw_mode in (1, 3):
            return self.equiv_speedctrl_time_s
        return self.equiv_currctrl_time_s

    def friction_n(self, velocity: Any) -> Any:
        """Friction at the slide for a velocity, the law the simulator's drives use [N].

        Parameters
        ----------
        velocity : float or array-like
            Slide velocity [mm/s] (rotary: [deg/s], friction in [Nm]).

        Returns
        -------
        float or numpy.ndarray
            ``Fv v + s(v) (Fc + Fs exp(-(v / vs)^2))`` with the sign s(v) linear within
            +-``friction_smoothing_mm_s`` (the Stribeck term only below 5 vs, as in the
            kernel).
        """
        import numpy as np

        v = np.asarray(velocity, dtype=np.float64)
        eps = max(self.friction_smoothing_mm_s, 1e-12)
        sg = np.where(np.abs(v) >= eps, np.sign(v), v / eps)
        u = v / max(self.stribeck_speed_mm_s, 1e-12)
        strib = np.where(np.abs(v) < 5.0 * self.stribeck_speed_mm_s,
                         self.stribeck_n * np.exp(-u * u), 0.0)
        out = self.viscous_n_per_mm_s * v + sg * (self.coulomb_n + strib)
        return float(out) if out.ndim == 0 else out

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the field if a value is out of range."""
        prefix = f"axes.{self.name}"
        _check(f"{prefix}.kv_m_min_per_mm", self.kv_m_min_per_mm, 0.05, 20.0)
        if self.ffw_mode not in (0, 1, 2, 3, 4):
            raise ConfigError(f"{prefix}.ffw_mode must be 0, 1, 2, 3 or 4 (MD32620), "
                              f"not {self.ffw_mode!r}")
        _check(f"{prefix}.ffw_weight", self.ffw_weight, 0.0, 1.0)
        if self.jerk_filter_type not in (0, 1, 2, 4):
            raise ConfigError(f"{prefix}.jerk_filter_type must be 0 (off), 1 (2nd order), "
                              f"2 (moving average) or 4 (double moving average), not "
                              f"{self.jerk_filter_type!r}")
        _check(f"{prefix}.jerk_time_s", self.jerk_time_s, 0.0, 0.1)
        _check(f"{prefix}.dyn_match_time_s", self.dyn_match_time_s, 0.0, 0.1)
        _check(f"{prefix}.equiv_speedctrl_time_s", self.equiv_speedctrl_time_s, 0.0, 0.05)
        _check(f"{prefix}.equiv_currctrl_time_s", self.equiv_currctrl_time_s, 1e-5, 0.01)
        _check(f"{prefix}.speed_kp_nm_s_per_rad", self.speed_kp_nm_s_per_rad, 1e-4, 1e3)
        _check(f"{prefix}.speed_ti_s", self.speed_ti_s, 1e-4, 10.0)
        _check(f"{prefix}.motor_inertia_kgm2", self.motor_inertia_kgm2, 1e-6, 10.0)
        _check(f"{prefix}.screw_pitch_mm", self.screw_pitch_mm, 0.5, 100.0)
        _check(f"{prefix}.mass_kg", self.mass_kg, 0.0, 1e5)
        _check(f"{prefix}.gear_ratio", self.gear_ratio, 1.0, 1e4)
        _check(f"{prefix}.load_inertia_kgm2", self.load_inertia_kgm2, 0.0, 1e4)
        for name in ("coulomb_n", "viscous_n_per_mm_s", "stribeck_n"):
            _check(f"{prefix}.{name}", getattr(self, name), 0.0, 1e6)
        _check(f"{prefix}.stribeck_speed_mm_s", self.stribeck_speed_mm_s, 1e-4, 1e3)
        _check(f"{prefix}.friction_smoothing_mm_s", self.friction_smoothing_mm_s, 1e-5, 10.0)
        _check(f"{prefix}.max_velocity_mm_min", self.max_velocity_mm_min, 1.0, 1e6)
        _check(f"{prefix}.max_accel_mm_s2", self.max_accel_mm_s2, 1.0, 1e6)
        _check(f"{prefix}.max_jerk_mm_s3", self.max_jerk_mm_s3, 1.0, 1e9)
        _check(f"{prefix}.kt_nm_per_a", self.kt_nm_per_a, 1e-3, 100.0)
        _check(f"{prefix}.current_limit_a", self.current_limit_a, 0.1, 1e4)
        _check(f"{prefix}.rated_torque_nm", self.rated_torque_nm, 1e-3, 1e5)
        _check(f"{prefix}.encoder_resolution", self.encoder_resolution, 1e-9, 0.1)
        _check(f"{prefix}.phase_resistance_ohm", self.phase_resistance_ohm, 0.0, 100.0)
        _check(f"{prefix}.thermal_resistance_k_per_w", self.thermal_resistance_k_per_w,
               1e-4, 100.0)
        _check(f"{prefix}.heat_capacity_j_per_k", self.heat_capacity_j_per_k, 1.0, 1e7)
        _check(f"{prefix}.ambient_temperature_c", self.ambient_temperature_c, -40.0, 80.0)
        _check(f"{prefix}.lf_smoothing_time_s", self.lf_smoothing_time_s, 1e-3, 10.0)
        _check(f"{prefix}.current_noise_a", self.current_noise_a, 0.0, 100.0)
        _check(f"{prefix}.encoder_noise", self.encoder_noise, 0.0, 1.0)
        _check(f"{prefix}.ripple_n", self.ripple_n, 0.0, 1e6)
        _check(f"{prefix}.ripple_phase_rad", self.ripple_phase_rad, -1e3, 1e3)


def _check(name: str, value: float, lo: float, hi: float) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or math.isnan(value):
        raise ConfigError(f"{name} must be a number, not {value!r}")
    if not lo <= value <= hi:
        raise ConfigError(f"{name} = {value!r} is out of range; allowed {lo:g} ... {hi:g}")


def dynamic_response_adaptation_times(axes: list[FeedAxis] | tuple[FeedAxis, ...]) -> dict[
    str, float
]:
    """MD32910 DYN_MATCH_TIME per axis: slowest equivalent time minus the axis' own [s].

    Parameters
    ----------
    axes : sequence of FeedAxis
        Interpolating axes.

    Returns
    -------
    dict
        Axis name -> dynamic response adaptation time [s].

    Notes
    -----
    The equivalent time is :attr:`FeedAxis.position_equivalent_time_s`; K3 / 802S example:
    0.060 x (1/0.5 - 1/2.5) = 0.096 s for a spindle with Kv 0.5 interpolating with a Z axis
    with Kv 2.5 (times in min x ... as in the manual; docs/reference/physics-and-performance.md
    §1.2).
    """
    eq = {ax.name: ax.position_equivalent_time_s for ax in axes}
    slowest = max(eq.values()) if eq else 0.0
    return {name: slowest - t for name, t in eq.items()}


def _default_axes() -> tuple[FeedAxis, ...]:
    """The thesis machine's feed axes (5-axis Spinner centre, 840D sl); see Machine docs."""
    return (
        FeedAxis("X1", mass_kg=400.0),
        FeedAxis("Y1", mass_kg=300.0),
        FeedAxis("Z1", mass_kg=250.0, coulomb_n=180.0),
        FeedAxis(
            "C1", rotary=True, gear_ratio=100.0, load_inertia_kgm2=2.0,
            motor_inertia_kgm2=0.001, coulomb_n=20.0, viscous_n_per_mm_s=0.02,
            stribeck_n=8.0, stribeck_speed_mm_s=1.0, friction_smoothing_mm_s=0.02,
            max_velocity_mm_min=54000.0, max_accel_mm_s2=720.0, max_jerk_mm_s3=7200.0,
            speed_kp_nm_s_per_rad=0.8, kt_nm_per_a=1.2, current_limit_a=20.0,
            rated_torque_nm=6.0, encoder_resolution=1e-5, encoder_noise=3.7e-5, ripple_n=1.0,
        ),
        FeedAxis(
            "B1", rotary=True, gear_ratio=120.0, load_inertia_kgm2=6.0,
            motor_inertia_kgm2=0.002, coulomb_n=40.0, viscous_n_per_mm_s=0.04,
            stribeck_n=15.0, stribeck_speed_mm_s=1.0, friction_smoothing_mm_s=0.02,
            max_velocity_mm_min=36000.0, max_accel_mm_s2=360.0, max_jerk_mm_s3=3600.0,
            speed_kp_nm_s_per_rad=1.5, kt_nm_per_a=1.4, current_limit_a=30.0,
            rated_torque_nm=10.0, encoder_resolution=1e-5, encoder_noise=3.7e-5, ripple_n=2.0,
        ),
    )


_SPINDLE_FIELDS = {f.name for f in dataclasses.fields(SpindleMotor)}
_AXIS_FIELDS = {f.name for f in dataclasses.fields(FeedAxis)}
_MACHINE_SCALARS = ("name", "cycle_time_s", "inner_steps", "tool_change_s")


@dataclass(frozen=True)
class Machine:
    """The simulated machine: feed axes, motor spindle, cycle times, axis numbers.

    Attributes
    ----------
    name : str
        Machine name (``meta.machine`` of recordings). Default ``"thesis-5axis-840Dsl"``.
    cycle_time_s : float
        Position-control cycle [s]. [S] 2 ms (thesis: 500 Hz)
    inner_steps : int
        Speed/current-controller steps per cycle [-]. [S] 16 (125 us, S120 booksize)
    axes : tuple of FeedAxis
        Feed axes, in axis-number order (X1 Y1 Z1 C1 B1).
    spindle : SpindleMotor
        The motor spindle (engineer C's :mod:`cnctwin.sim.spindle`).
    spindle_name : str
        Axis name of the spindle. ``"SP1"``
    tool_change_s : float
        Chip-to-chip time of an M6 tool change [s]. [E] 4 (machining centres with a
        magazine: 2-6 s); the spindle stops first.
    axis_map : dict
        Axis number (``|n`` of the HF addresses) -> name; default ``{1: "X1", ..., 6: "SP1"}``.
    """

    name: str = "thesis-5axis-840Dsl"
    cycle_time_s: float = 0.002
    inner_steps: int = 16
    axes: tuple[FeedAxis, ...] = field(default_factory=_default_axes)
    spindle: SpindleMotor = field(default_factory=SpindleMotor)
    spindle_name: str = "SP1"
    tool_change_s: float = 4.0
    axis_map: dict[int, str] = field(
        default_factory=lambda: {1: "X1", 2: "Y1", 3: "Z1", 4: "C1", 5: "B1", 6: "SP1"}
    )

    def __post_init__(self) -> None:
        self.validate()

    @classmethod
    def thesis_default(cls) -> Machine:
        """The thesis machine (5-axis Spinner centre, SINUMERIK 840D sl, S120 drives)."""
        return cls()

    # ------------------------------------------------------------ access
    @property
    def axis_names(self) -> tuple[str, ...]:
        """Feed-axis names in order."""
        return tuple(ax.name for ax in self.axes)

    def axis(self, name: str) -> FeedAxis:
        """The feed axis called ``name``; :class:`ConfigError` lists the valid names."""
        for ax in self.axes:
            if ax.name == name:
                return ax
        raise ConfigError(f"no feed axis {name!r}; axes are {', '.join(self.axis_names)}")

    def validate(self) -> None:
        """Check every value; raise :class:`ConfigError` naming the field."""
        _check("cycle_time_s", self.cycle_time_s, 1e-4, 0.02)
        _check("tool_change_s", self.tool_change_s, 0.0, 600.0)
        if not isinstance(self.inner_steps, int) or not 1 <= self.inner_steps <= 256:
            raise ConfigError(f"inner_steps must be an integer 1 ... 256, not "
                              f"{self.inner_steps!r}")
        names = [ax.name for ax in self.axes]
        if len(set(names)) != len(names):
            raise ConfigError(f"axis names must be unique, got {names}")
        for ax in self.axes:
            ax.validate()
        missing = [n for n in (*names, self.spindle_name) if n not in self.axis_map.values()]
        if missing:
            raise ConfigError(f"axis_map {self.axis_map} lacks {missing}; give every axis a "
                              "number")

    # ------------------------------------------------------------ dict / TOML
    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (TOML-able): scalars, ``axes.<name>``, ``spindle``, ``axis_map``."""
        return {
            "name": self.name,
            "cycle_time_s": self.cycle_time_s,
            "inner_steps": self.inner_steps,
            "tool_change_s": self.tool_change_s,
            "spindle_name": self.spindle_name,
            "axis_map": {str(k): v for k, v in sorted(self.axis_map.items())},
            "axes": {ax.name: _axis_dict(ax) for ax in self.axes},
            "spindle": dataclasses.asdict(self.spindle),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, source: str = "machine description") -> Machine:
        """Build from :meth:`to_dict` output; unknown keys raise :class:`ConfigError`."""
        known = {*_MACHINE_SCALARS, "spindle_name", "axis_map", "axes", "spindle"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"{source}: unknown keys {unknown}; valid keys: {sorted(known)}")
        kw: dict[str, Any] = {k: data[k] for k in (*_MACHINE_SCALARS, "spindle_name")
                              if k in data}
        if "axis_map" in data:
            try:
                kw["axis_map"] = {int(k): str(v) for k, v in data["axis_map"].items()}
            except (ValueError, AttributeError) as exc:
                raise ConfigError(f"{source}: axis_map must map numbers to names") from exc
        if "axes" in data:
            axes = []
            for name, fields in data["axes"].items():
                bad = sorted(set(fields) - _AXIS_FIELDS)
                if bad:
                    raise ConfigError(f"{source}: axes.{name} has unknown keys {bad}; valid "
                                      f"keys: {sorted(_AXIS_FIELDS - {'name'})}")
                axes.append(FeedAxis(**{**fields, "name": name}))
            kw["axes"] = tuple(axes)
        if "spindle" in data:
            bad = sorted(set(data["spindle"]) - _SPINDLE_FIELDS)
            if bad:
                raise ConfigError(f"{source}: spindle has unknown keys {bad}; valid keys: "
                                  f"{sorted(_SPINDLE_FIELDS)}")
            kw["spindle"] = SpindleMotor(**data["spindle"])
        return cls(**kw)

    def to_toml(self, path: str | Path) -> Path:
        """Write the description as TOML (``tomli_w``); returns the path."""
        p = Path(path)
        p.write_bytes(tomli_w.dumps(self.to_dict()).encode("utf-8"))
        return p

    @classmethod
    def from_toml(cls, path: str | Path) -> Machine:
        """Read a description written by :meth:`to_toml` (or by hand; missing keys = defaults)."""
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
        return cls.from_dict(data, source=str(p))

    # ------------------------------------------------------------ overrides
    def valid_override_keys(self) -> list[str]:
        """Every dotted key :meth:`with_overrides` accepts."""
        keys = [*_MACHINE_SCALARS]
        for ax in self.axes:
            keys += [f"axes.{ax.name}.{f}" for f in sorted(_AXIS_FIELDS - {"name"})]
        keys += [f"spindle.{f}" for f in sorted(_SPINDLE_FIELDS)]
        return keys

    def with_overrides(self, overrides: Mapping[str, Any]) -> Machine:
        """A copy with dotted-path values replaced.

        Parameters
        ----------
        overrides : mapping
            ``{"axes.X1.kv_m_min_per_mm": 3.0, "spindle.kt_nm_per_a": 1.1, "cycle_time_s": ...}``.

        Raises
        ------
        ConfigError
            For an unknown key (the message lists the valid keys) or an out-of-range value.

        Examples
        --------
        >>> m = Machine.thesis_default().with_overrides({"axes.X1.kv_m_min_per_mm": 3.0})
        >>> m.axis("X1").kv_m_min_per_mm
        3.0
        """
        valid = set(self.valid_override_keys())
        unknown = sorted(k for k in overrides if k not in valid)
        if unknown:
            raise ConfigError(
                f"unknown override keys {unknown}; valid keys are: {', '.join(sorted(valid))}"
            )
        top: dict[str, Any] = {}
        axis_changes: dict[str, dict[str, Any]] = {}
        spindle_changes: dict[str, Any] = {}
        for key, value in overrides.items():
            parts = key.split(".")
            if parts[0] == "axes":
                axis_changes.setdefault(parts[1], {})[parts[2]] = value
            elif parts[0] == "spindle":
                spindle_changes[parts[1]] = value
            else:
                top[key] = value
        axes = tuple(
            dataclasses.replace(ax, **axis_changes[ax.name]) if ax.name in axis_changes else ax
            for ax in self.axes
        )
        spindle = (dataclasses.replace(self.spindle, **spindle_changes) if spindle_changes
                   else self.spindle)
        return dataclasses.replace(self, axes=axes, spindle=spindle, **top)


def _axis_dict(ax: FeedAxis) -> dict[str, Any]:
    d = dataclasses.asdict(ax)
    d.pop("name")
    return d
