/*
 * motor_model.h - DC-motor model: wheel torque command -> H-bridge duty (portable C, no AVR headers).
 *
 * Steady-state brushed DC motor behind a gearbox of ratio G and efficiency eta:
 *   tau_m = tau_w / (G * eta)          motor shaft torque              [N m]
 *   I     = tau_m / k_t                armature current                [A]
 *   omega_m = G * omega_w              motor speed from encoder        [rad/s]
 *   V     = I * R + k_e * omega_m      terminal voltage (k_e = k_t)    [V]
 *   d     = V / V_supply               duty, clamped to [-1, 1]
 * Winding inductance is neglected: its time constant (~1 ms) is well below the 10 ms period.
 */
#ifndef FW_MOTOR_MODEL_H
#define FW_MOTOR_MODEL_H

#include <stdint.h>

typedef struct {
    float supply_v;           /* H-bridge supply voltage [V] (> 0) */
    float torque_constant;    /* k_t [N m / A] = k_e [V s / rad] (> 0) */
    float resistance_ohm;     /* winding resistance R [ohm] (> 0) */
    float gear_ratio;         /* G: motor turns per wheel turn (> 0) */
    float gear_efficiency;    /* eta in (0, 1] */
} motor_model_t;

/* The model is linear in torque and speed: d = tau * duty_per_nm + omega * duty_per_radps
 * (then clamped). The firmware precomputes the two coefficients once, so its control step has
 * no division. */
typedef struct {
    float duty_per_nm;        /* R / (G eta k_t V_supply)  [1 / (N m)] */
    float duty_per_radps;     /* k_t G / V_supply           [s / rad] */
} motor_coeffs_t;

motor_coeffs_t motor_coeffs(const motor_model_t *m);
float motor_duty_from_coeffs(const motor_coeffs_t *c, float torque_nm, float wheel_speed_radps);

/* Duty in [-1, 1] that produces wheel torque `torque_nm` at wheel speed `wheel_speed_radps`. */
float motor_duty_from_torque(const motor_model_t *m, float torque_nm, float wheel_speed_radps);

/* Wheel torque [N m] produced by duty `duty` in [-1, 1] at wheel speed `wheel_speed_radps`
 * (the inverse of motor_duty_from_torque inside the unsaturated range; the emulator's plant). */
float motor_torque_from_duty(const motor_model_t *m, float duty, float wheel_speed_radps);

/* Duty [-1, 1] -> signed PWM compare value in [-top, top], rounded to nearest. */
int16_t motor_duty_to_counts(float duty, uint16_t top);

#endif
