/*
 * main.c - motor-board firmware entry point (ATmega328P): glues board.c to the peripherals.
 *
 * Main loop (woken by every interrupt, at least once per millisecond by the Timer2 tick):
 *   1. encoder snapshot; every received UART byte -> board_receive (decoder, message rules,
 *      replies: TELEMETRY acknowledges each accepted command at once)
 *   2. every 10 ms (control tick): encoder counts latched in the tick interrupt at the period
 *      boundary -> board_control_step (speed over exactly 10 ms -> duty),
 *      hardware watchdog kick
 *   3. then board_poll once per millisecond: command watchdog, TELEMETRY / STATUS when due
 *   4. PWM outputs when the board changed them; sleep (idle mode) until the next interrupt
 * The hardware watchdog (60 ms) resets the MCU when the loop stops running the control step;
 * after any reset the board comes up with torque 0 and the RESET flag (host handshakes again).
 */
#include <avr/interrupt.h>

#include "board.h"
#include "config.h"
#include "hal.h"

static bool uart_send(const uint8_t *frame, uint16_t len, void *ctx)
{
    (void)ctx;
    return hal_uart_write(frame, len);
}

static uint16_t uart_queued(void *ctx)
{
    (void)ctx;
    return hal_uart_tx_queued();
}

static void apply_pwm(const board_t *b)
{
    int16_t left, right;
    board_pwm(b, &left, &right);
    hal_pwm_set(left, right);
}

int main(void)
{
    static board_t board;
    const board_config_t cfg = {
        .motor = {MOTOR_SUPPLY_V, MOTOR_TORQUE_CONSTANT_NM_PER_A, MOTOR_RESISTANCE_OHM,
                  MOTOR_GEAR_RATIO, MOTOR_GEAR_EFFICIENCY},
        .pwm_top = PWM_TOP,
        .ticks_per_rev = ENCODER_TICKS_PER_REV,
        .hard_limit_e4nm = (uint16_t)(DEFAULT_TORQUE_LIMIT_NM * 1e4f + 0.5f),
        .default_watchdog_ms = COMMAND_WATCHDOG_MS,
        .default_telemetry_period_ms = CONTROL_PERIOD_MS,
        /* e4nm per mrad/s = (N m per rad/s) * 1e4 / 1e3 */
        .brake_gain_e4nm_per_mradps = BRAKE_GAIN_NM_PER_RADPS * 10.0f,
        .brake_limit_e4nm = (uint16_t)(BRAKE_TORQUE_LIMIT_NM * 1e4f + 0.5f),
        .brake_rest_ms = BRAKE_REST_MS,
        .brake_max_ms = BRAKE_MAX_MS,
    };
    hal_init();
    board_init(&board, &cfg, 0, uart_send, uart_queued, 0);
    apply_pwm(&board);
    sei();
    uint32_t last_poll_ms = 0;
    for (;;) {
        hal_loop_busy();
        const uint32_t now_ms = hal_millis();
        int32_t left, right;
        hal_encoders_read(&left, &right);
        board_encoders(&board, left, right);
        uint8_t byte;
        while (hal_uart_read(&byte)) {
            board_receive(&board, byte, now_ms);
        }
        uint8_t periods;
        if (hal_take_control_tick(&left, &right, &periods)) {
            board_control_step(&board, left, right, (uint32_t)periods * CONTROL_PERIOD_MS * 1000UL);
            hal_watchdog_kick();
            hal_led((board.flags & (PROTO_FLAG_WATCHDOG | PROTO_FLAG_ESTOP)) == 0);
        }
        /* after the control step, so TELEMETRY carries this period's encoder counts; a wake-up
         * by a TX-empty or encoder interrupt alone has nothing new to decide */
        if (now_ms != last_poll_ms) {
            last_poll_ms = now_ms;
            board_poll(&board, now_ms);
        }
        board_service_tx(&board, now_ms);
        if (board_take_outputs_changed(&board)) {
            apply_pwm(&board);
        }
        hal_idle();
    }
}
