/*
 * config.h - compile-time configuration of the motor board (ATmega328P, Arduino Uno/Nano).
 *
 * Everything a user adapts to their robot lives here: clock, baud rate, pins, the DC-motor
 * model (supply voltage, torque constant, winding resistance, gear ratio) and the safety limits.
 * Plain #defines only, no AVR headers: the host tests and the simavr harness include this file
 * too, so the emulated wheel model uses the same constants as the firmware.
 *
 * Units are in the names (_V, _OHM, _NM, _MS, _HZ ...). Values may be overridden on the make
 * command line, e.g. `make -C firmware CFLAGS_EXTRA=-DMOTOR_SUPPLY_V=7.4f`.
 */
#ifndef FW_CONFIG_H
#define FW_CONFIG_H

/* ---- clock and link ------------------------------------------------------------------- */
#ifndef F_CPU
#define F_CPU 16000000UL            /* Uno/Nano crystal */
#endif
#define UART_BAUD 115200UL          /* U2X=1, UBRR0=16 -> 117647 baud (+2.1 %), as Arduino does */
#define UART_RX_BUFFER_BYTES 128u   /* power of two */
#define UART_TX_BUFFER_BYTES 256u   /* power of two, at most 256 */

/* ---- timing --------------------------------------------------------------------------- */
#define TICK_HZ 1000u               /* Timer2 CTC tick: millisecond clock */
#define CONTROL_PERIOD_MS 10u       /* control step + telemetry: 100 Hz */
#define COMMAND_WATCHDOG_MS 200u    /* no valid torque command for this long -> zero PWM + flag */

/* ---- PWM (Timer1, phase-correct, TOP = ICR1) -------------------------------------------- */
#define PWM_FREQUENCY_HZ 20000u     /* inaudible; f = F_CPU / (2 * TOP) */
#define PWM_TOP ((uint16_t)(F_CPU / (2UL * PWM_FREQUENCY_HZ)))   /* 400 steps */

/* ---- DC-motor model (per wheel; see firmware/README.md "Motor model") --------------------
 * Wheel torque tau_w [N m] -> motor torque tau_m = tau_w / (G * eta)
 * -> current I = tau_m / k_t -> voltage V = I R + k_e * G * omega_w (k_e = k_t in SI units)
 * -> duty d = V / V_supply, clamped to [-1, 1]. omega_w is the wheel speed from the encoder.
 * Defaults: a 12 V class brushed gearmotor (Pololu 37D 30:1 like).                         */
#ifndef MOTOR_SUPPLY_V
#define MOTOR_SUPPLY_V 12.0f
#endif
#ifndef MOTOR_TORQUE_CONSTANT_NM_PER_A
#define MOTOR_TORQUE_CONSTANT_NM_PER_A 0.0175f   /* k_t, equal to k_e in V s/rad */
#endif
#ifndef MOTOR_RESISTANCE_OHM
#define MOTOR_RESISTANCE_OHM 2.4f
#endif
#ifndef MOTOR_GEAR_RATIO
#define MOTOR_GEAR_RATIO 30.0f                   /* motor turns per wheel turn */
#endif
#ifndef MOTOR_GEAR_EFFICIENCY
#define MOTOR_GEAR_EFFICIENCY 1.0f               /* eta in (0, 1] */
#endif

/* ---- encoders --------------------------------------------------------------------------- */
#define ENCODER_TICKS_PER_REV 1440L              /* wheel-side counts per revolution, x4 decoding */

/* ---- safety defaults (the limits/config message may lower them at run time) -------------- */
#define DEFAULT_TORQUE_LIMIT_NM 0.15f            /* |tau_w| clamp, matches the scenario default */
#define MAX_TORQUE_LIMIT_NM 2.0f                 /* a config message can never raise it above this */

/* ---- stop brake on command loss (docs/safety.md; the emulated board core/serial/motor_board.py
 * uses the same numbers). After the command watchdog trips, each wheel is regulated to zero speed:
 * tau = clamp(-BRAKE_GAIN * omega_encoder, +-min(BRAKE_TORQUE_LIMIT, torque limit)); released
 * (H-bridge off) once both wheels stayed within one encoder count of a reference position for
 * BRAKE_REST_MS (at rest), or after BRAKE_MAX_MS whatever the speed.                                                  */
#define BRAKE_GAIN_NM_PER_RADPS 0.05f
#define BRAKE_TORQUE_LIMIT_NM 0.10f
#define BRAKE_REST_MS 50u
#define BRAKE_MAX_MS 1000u

/* ---- pins (Arduino Uno/Nano names in brackets; see firmware/README.md) -------------------
 * PB1 [D9]  OC1A  PWM left        PB3 [D11] DIR left    PD2 [D2] left  encoder A  (PCINT18)
 * PB2 [D10] OC1B  PWM right       PB4 [D12] DIR right   PD4 [D4] left  encoder B  (PCINT20)
 * PD0 [D0]  RXD   PD1 [D1] TXD    PB5 [D13] LED status  PD3 [D3] right encoder A  (PCINT19)
 *                                                       PD5 [D5] right encoder B  (PCINT21)
 * Port D holds only inputs (UART, encoders with pull-ups) and is written once at start-up;
 * every output is on port B. PB0 (ICP1) stays free: Timer1 uses ICR1 as its TOP.          */
#define PIN_ENC_LEFT_A 2    /* bit in PORTD */
#define PIN_ENC_RIGHT_A 3
#define PIN_ENC_LEFT_B 4
#define PIN_ENC_RIGHT_B 5
#define PIN_DIR_LEFT 3      /* bit in PORTB */
#define PIN_DIR_RIGHT 4     /* bit in PORTB */
#define PIN_PWM_LEFT 1      /* bit in PORTB (OC1A) */
#define PIN_PWM_RIGHT 2     /* bit in PORTB (OC1B) */
#define PIN_LED 5           /* bit in PORTB */

#endif /* FW_CONFIG_H */
