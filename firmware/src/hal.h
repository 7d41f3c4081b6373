/*
 * hal.h - ATmega328P peripherals of the motor board (AVR only).
 *
 *   USART0  115200 8N1, interrupt-driven RX/TX ring buffers
 *   Timer1  phase-correct PWM, TOP = ICR1 (20 kHz), OC1A = left (D9), OC1B = right (D10),
 *           direction on D7 (left) and D8 (right): sign-magnitude H-bridge input (PWM + DIR)
 *   Timer2  CTC 1 kHz tick: millisecond clock and the 100 Hz control flag
 *   PCINT2  quadrature encoders on D2/D4 (left A/B) and D3/D5 (right A/B), x4 decoding
 *   WDT     hardware watchdog, 60 ms, reset by the control step
 *   GPIOR0  1 while the main loop works, 0 while it sleeps (the emulator measures loop cycles)
 */
#ifndef FW_HAL_H
#define FW_HAL_H

#include <stdbool.h>
#include <stdint.h>

void hal_init(void);                       /* all peripherals; interrupts still disabled */

/* UART */
bool hal_uart_read(uint8_t *byte);         /* false when no byte is waiting */
uint8_t hal_uart_rx_overruns(void);        /* bytes lost to a full RX buffer (saturating) */
uint16_t hal_uart_tx_free(void);           /* bytes of space in the TX ring */
uint16_t hal_uart_tx_queued(void);         /* bytes waiting to be sent */
bool hal_uart_write(const uint8_t *data, uint16_t len);   /* all or nothing */

/* PWM: signed compare counts in [-PWM_TOP, PWM_TOP]; sign selects the DIR pin */
void hal_pwm_set(int16_t left_counts, int16_t right_counts);

/* Encoders: accumulated x4 counts since reset (atomic snapshot) */
void hal_encoders_read(int32_t *left_ticks, int32_t *right_ticks);

/* Time */
uint32_t hal_millis(void);                 /* atomic snapshot of the ms clock */
/* true once per CONTROL_PERIOD_MS: the encoder counts latched by the tick interrupt at the
 * period boundary and the number of periods since the previous call (normally 1) */
bool hal_take_control_tick(int32_t *left_ticks, int32_t *right_ticks, uint8_t *periods);

/* Watchdog + reset cause */
void hal_watchdog_kick(void);
uint8_t hal_reset_cause(void);             /* MCUSR as captured at start (bit 3 = watchdog reset) */

/* Main-loop idle: sleeps until the next interrupt when no UART byte and no tick is waiting */
void hal_idle(void);
void hal_loop_busy(void);                  /* marks the start of loop work (GPIOR0 = 1) */

void hal_led(bool on);

#endif
