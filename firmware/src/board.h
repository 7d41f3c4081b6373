/*
 * board.h - the motor board's behaviour (docs/serial-protocol.md section 4), portable C99.
 *
 * Pure logic, no AVR headers: bytes in (board_receive), time and encoder counts in
 * (board_control_step, board_poll), frames out through the `send` callback, PWM compare values out
 * (board_pwm). main.c glues it to the hardware; the host can compile it too.
 *
 * Rules implemented:
 *   boot: torque 0, flags WATCHDOG | RESET, counters 0, cmd_seq 0
 *   HELLO (any version) -> HELLO_ACK, RESET cleared; the HELLO_ACK goes out in version-1 framing
 *       (CRC-16) when the HELLO asked for version 1, so an old host reports the mismatch
 *   TORQUE_CMD (accepted) -> cmd_seq = seq, watchdog restarted, WATCHDOG cleared,
 *       applied = clamp(cmd, +-limit) and CLAMPED = any wheel clamped; while the e-stop is
 *       engaged the command is counted in cmd_seq (and restarts the watchdog) but torque stays 0
 *   now - last TORQUE_CMD >= watchdog_ms -> WATCHDOG set, watchdog_trips += 1 on the edge; if a
 *       command had been accepted since boot (and no e-stop), the stop brake starts (BRAKING set):
 *       every control step each wheel gets tau = clamp(-brake_gain * omega, +-min(brake limit,
 *       torque limit)), omega from the encoders; released (torque 0, H-bridge off, BRAKING cleared)
 *       once both wheels stayed within one encoder count of a reference position for
 *       brake_rest_ms (at rest), or after brake_max_ms.
 *       A new TORQUE_CMD or an e-stop ends the brake at once. docs/safety.md.
 *   STOP -> like a TORQUE_CMD for the watchdog and the acknowledgement, torque command 0; starts
 *       the brake if a TORQUE_CMD was accepted since the last brake start (once per stop)
 *   ESTOP engage -> torque 0 at once, ESTOP set; release -> ESTOP cleared, torque 0 until the next command
 *   CONFIG -> values clamped into [0, hard limit] N m, [20, 500] ms, [5, 1000] ms, applied at once,
 *       CONFIG_ACK with the values in force
 *   HEARTBEAT -> echoed with the same body
 *   rejected frames -> crc_errors / frame_errors / type_errors, RX_ERROR until the next TELEMETRY
 *   TELEMETRY right after every accepted TORQUE_CMD (the acknowledgement, cmd_seq = its seq);
 *       after a rejected frame at once (negative acknowledgement, RX_ERROR set), at most one per
 *       telemetry_period_ms / 2; on its own every telemetry_period_ms while no TORQUE_CMD was
 *       accepted for 2 x telemetry_period_ms
 *   a TELEMETRY is queued only behind less than one frame of other bytes; otherwise it waits and
 *       goes out with the newest state (cumulative cmd_seq), so it is never stale
 *   STATUS every 200 ms
 *   duty from the applied torque through the DC-motor model (motor_model.h) with the wheel speed
 *   measured from the encoders, recomputed on every command and every control step
 */
#ifndef FW_BOARD_H
#define FW_BOARD_H

#include <stdbool.h>
#include <stdint.h>

#include "motor_model.h"
#include "protocol.h"

#define BOARD_FIRMWARE_MAJOR 2u
#define BOARD_FIRMWARE_MINOR 0u
#define BOARD_STATUS_PERIOD_MS 200u
#define BOARD_WATCHDOG_MIN_MS 20u
#define BOARD_WATCHDOG_MAX_MS 500u
#define BOARD_TELEMETRY_MIN_MS 5u
#define BOARD_TELEMETRY_MAX_MS 1000u

/* sends one complete wire frame; returns false when it could not be queued */
typedef bool (*board_send_fn)(const uint8_t *frame, uint16_t len, void *ctx);
/* bytes still waiting in the transmit queue */
typedef uint16_t (*board_queued_fn)(void *ctx);

typedef struct {
    motor_model_t motor;
    uint16_t pwm_top;               /* PWM compare value of duty 1 */
    uint16_t ticks_per_rev;
    uint16_t hard_limit_e4nm;       /* compiled-in maximum torque limit */
    uint16_t default_watchdog_ms;
    uint16_t default_telemetry_period_ms;
    float brake_gain_e4nm_per_mradps;   /* stop brake: torque per wheel speed (config.h BRAKE_*) */
    uint16_t brake_limit_e4nm;          /* stop brake torque bound */
    uint16_t brake_rest_ms;             /* release after this long at rest */
    uint16_t brake_max_ms;              /* release after this long whatever the speed */
} board_config_t;

typedef struct {
    board_config_t cfg;
    motor_coeffs_t coeffs;          /* motor model, precomputed */
    uint32_t vel_dt_us;             /* control period the velocity factor was computed for */
    float vel_factor;               /* mrad/s per tick at vel_dt_us */
    board_send_fn send;
    board_queued_fn queued;
    void *send_ctx;
    proto_decoder_t decoder;
    /* configuration in force */
    uint16_t torque_limit_e4nm;
    uint16_t watchdog_ms;
    uint16_t telemetry_period_ms;
    /* state */
    uint8_t flags;
    int16_t command_e4nm[2];        /* last accepted command, clamped */
    int16_t applied_e4nm[2];        /* torque actually applied (0 under watchdog / e-stop) */
    int16_t pwm_counts[2];          /* signed compare values in [-pwm_top, pwm_top] */
    uint8_t cmd_seq;
    uint8_t tx_seq;
    uint8_t last_rx_seq;
    bool have_rx_seq;
    uint32_t boot_ms;
    uint32_t last_cmd_ms;
    uint32_t last_telemetry_ms;
    uint32_t last_nack_ms;
    bool have_cmd;                  /* a TORQUE_CMD was accepted since boot */
    bool have_nack;
    bool telemetry_pending;         /* a TELEMETRY waits for the TX queue to drain */
    uint32_t next_status_ms;
    /* encoders */
    int32_t ticks[2];               /* latest counts (TELEMETRY) */
    int32_t control_ticks[2];       /* counts at the last control step (velocity) */
    int16_t vel_mradps[2];
    bool outputs_changed;           /* pwm_counts changed since board_take_outputs_changed */
    /* stop brake (flag PROTO_FLAG_BRAKING) */
    int16_t brake_e4nm[2];          /* brake torque of the last control step */
    uint32_t brake_elapsed_us;
    uint32_t rest_elapsed_us;       /* time both wheels stayed within 1 count of rest_ref_ticks */
    int32_t rest_ref_ticks[2];
    uint16_t brakes;                /* brake episodes since boot (wrapping) */
    bool brake_armed;               /* a TORQUE_CMD since the last brake start */
    /* counters (wrapping) */
    uint16_t crc_errors;
    uint16_t frame_errors;
    uint16_t type_errors;
    uint16_t rx_gaps;
    uint16_t watchdog_trips;
    uint16_t tx_dropped;            /* frames the TX queue could not take */
} board_t;

void board_init(board_t *b, const board_config_t *cfg, uint32_t now_ms, board_send_fn send,
                board_queued_fn queued, void *send_ctx);

/* every main-loop pass: sends a TELEMETRY held back while the queue was busy */
void board_service_tx(board_t *b, uint32_t now_ms);

/* latest encoder counts (x4, since boot): call before board_receive so acknowledgements carry
 * fresh positions */
void board_encoders(board_t *b, int32_t left_ticks, int32_t right_ticks);

/* one received byte (decoder, then the message rules) */
void board_receive(board_t *b, uint8_t byte, uint32_t now_ms);

/* every control period: encoder counts (x4, since boot) and the time elapsed since the last
 * call [us] -> wheel velocity -> duty */
void board_control_step(board_t *b, int32_t left_ticks, int32_t right_ticks, uint32_t dt_us);

/* often (every ms): watchdog, periodic TELEMETRY and STATUS when due */
void board_poll(board_t *b, uint32_t now_ms);

/* PWM outputs to apply now */
void board_pwm(const board_t *b, int16_t *left_counts, int16_t *right_counts);

/* true once after the PWM outputs changed */
bool board_take_outputs_changed(board_t *b);

#endif
