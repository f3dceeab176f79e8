"""Spindle drive model: PMSM motor spindle with speed/current control, friction and heating.

Layers (pvlib style):

* :class:`SpindleMotor`: the description (every parameter with unit, default and source).
* :func:`simulate_spindle`: integrates the drive at the 125 us controller cycle and returns one
  sample per 2 ms position-control cycle (what the edge device records) as a
  :class:`SpindleTrace`; ``trace.state`` continues a simulation chunk by chunk.

Current convention: every current the drive reports (``CURRENT``, r0068, r0078) is in
**A rms**, as in the SINAMICS parameter list. Internally the dq model uses the
amplitude-invariant Park transform (peak values), so with ``p`` pole pairs

    Te = 1.5 p (psi_pm + (Ld - Lq) id) iq          (id, iq peak)
    Kt = Te / Iq_rms = 1.5 * sqrt(2) * p * psi_pm   (at id = 0)

and ``SpindleMotor.flux_linkage_vs`` is derived from ``kt_nm_per_a`` with that relation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["SpindleMotor"]


@dataclass(frozen=True)
class SpindleMotor:
    """Motor spindle (PMSM) of the thesis machine and its SINAMICS drive.

    Defaults describe the 5-axis Spinner machining centre of the thesis (SINUMERIK 840D sl,
    S120 drive). Kinds: [T] thesis, [S] datasheet/manual (see docs/simulator.md and
    physics-and-performance.md §2), [D] derived, [E] engineering estimate.

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
        makes the mean current non-linear below ~1100 rpm (thesis §4.1). [E] 0.12
    stribeck_speed_rpm : float
        Stribeck decay speed [rpm]. [E] 250
    viscous_rolloff_speed_rpm : float
        Speed above which the viscous friction grows less than linearly (shear thinning and
        oil-film heating of the bearings) so that mean Iq departs from the straight line above
        ~5000 rpm (thesis Fig. 4.1) [rpm]. [E] 5000
    viscous_rolloff_width_rpm : float
        Width W of the roll-off: the viscous term above the knee is
        B (N_k + W tanh((N - N_k)/W)) [rpm]. [E] 6000
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
        DC-link voltage [V]. [S] ALM 600-720 V (physics-and-performance.md §2)
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
        this size: 0.01-0.03; J is not given in the thesis, physics-and-performance.md §4)
    current_loop_time_constant_s : float
        Equivalent first-order time constant of the closed current loop [s].
        [S] torque rise time 0.5-0.8 ms on S120 (physics-and-performance.md §1.3); 0.0005
    speed_ctrl_kp_nm_s_per_rad : float
        Speed-controller proportional gain [Nm s/rad]. [E] 2.4 (~25 Hz with J = 0.015)
    speed_ctrl_ti_s : float
        Speed-controller integral time [s]. [E] 0.02
    position_ctrl_kv_per_s : float
        Spindle position-loop gain in rigid tapping (mode 1) [1/s]. [S] Kv <= 3 (m/min)/mm
        = 50 1/s for 840D sl spindles (physics-and-performance.md §1.2); 30
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
    stribeck_torque_nm: float = 0.12
    stribeck_speed_rpm: float = 250.0
    viscous_rolloff_speed_rpm: float = 5000.0
    viscous_rolloff_width_rpm: float = 6000.0
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
