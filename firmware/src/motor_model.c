/* motor_model.c - see motor_model.h for the equations. Portable C99. */
#include "motor_model.h"

static float clamp_unit(float x)
{
    if (!(x == x)) {            /* NaN -> 0: never drive on garbage */
        return 0.0f;
    }
    if (x > 1.0f) {
        return 1.0f;
    }
    if (x < -1.0f) {
        return -1.0f;
    }
    return x;
}

float motor_duty_from_torque(const motor_model_t *m, float torque_nm, float wheel_speed_radps)
{
    const float motor_torque_nm = torque_nm / (m->gear_ratio * m->gear_efficiency);
    const float current_a = motor_torque_nm / m->torque_constant;
    const float back_emf_v = m->torque_constant * m->gear_ratio * wheel_speed_radps;
    const float voltage_v = current_a * m->resistance_ohm + back_emf_v;
    return clamp_unit(voltage_v / m->supply_v);
}

motor_coeffs_t motor_coeffs(const motor_model_t *m)
{
    motor_coeffs_t c;
    c.duty_per_nm = m->resistance_ohm /
                    (m->gear_ratio * m->gear_efficiency * m->torque_constant * m->supply_v);
    c.duty_per_radps = m->torque_constant * m->gear_ratio / m->supply_v;
    return c;
}

float motor_duty_from_coeffs(const motor_coeffs_t *c, float torque_nm, float wheel_speed_radps)
{
    return clamp_unit(torque_nm * c->duty_per_nm + wheel_speed_radps * c->duty_per_radps);
}

float motor_torque_from_duty(const motor_model_t *m, float duty, float wheel_speed_radps)
{
    const float voltage_v = clamp_unit(duty) * m->supply_v;
    const float back_emf_v = m->torque_constant * m->gear_ratio * wheel_speed_radps;
    const float current_a = (voltage_v - back_emf_v) / m->resistance_ohm;
    return current_a * m->torque_constant * m->gear_ratio * m->gear_efficiency;
}

int16_t motor_duty_to_counts(float duty, uint16_t top)
{
    const float scaled = clamp_unit(duty) * (float)top;
    const int32_t counts = (int32_t)(scaled >= 0.0f ? scaled + 0.5f : scaled - 0.5f);
    return (int16_t)counts;
}
