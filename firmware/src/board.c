/* board.c - motor-board behaviour; see board.h and docs/serial-protocol.md section 4. */
#include "board.h"

#include <string.h>

static bool send_msg_version(board_t *b, proto_msg_t *m, uint8_t version)
{
    uint8_t wire[PROTO_MAX_WIRE_BYTES];
    m->version = version;
    m->seq = b->tx_seq;
    const uint16_t n = proto_encode(m, false, wire, sizeof wire);
    if (n == 0 || !b->send(wire, n, b->send_ctx)) {
        b->tx_dropped++;
        return false;
    }
    b->tx_seq++;   /* one per frame actually sent, so the host sees no false gap */
    return true;
}

static bool send_msg(board_t *b, proto_msg_t *m)
{
    return send_msg_version(b, m, PROTO_VERSION);
}

#define TELEMETRY_WIRE_BYTES 18u

static void send_telemetry(board_t *b, uint32_t now_ms)
{
    proto_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = PROTO_TELEMETRY;
    m.u.telemetry.left_ticks = (int16_t)(uint16_t)b->ticks[0];
    m.u.telemetry.right_ticks = (int16_t)(uint16_t)b->ticks[1];
    m.u.telemetry.left_vel_mradps = b->vel_mradps[0];
    m.u.telemetry.right_vel_mradps = b->vel_mradps[1];
    m.u.telemetry.cmd_seq = b->cmd_seq;
    m.u.telemetry.flags = b->flags;
    /* a TELEMETRY acknowledges cmd_seq and everything before it: behind a busy queue it waits
     * and then goes out once, with the newest state */
    if (b->queued(b->send_ctx) >= TELEMETRY_WIRE_BYTES) {
        b->telemetry_pending = true;
        return;
    }
    b->telemetry_pending = !send_msg(b, &m);
    if (!b->telemetry_pending) {
        b->flags &= (uint8_t)~PROTO_FLAG_RX_ERROR;
        b->last_telemetry_ms = now_ms;
    }
}

static int16_t clamp_torque(int16_t v, uint16_t limit, bool *clamped)
{
    const int32_t lim = limit;
    if (v > lim) {
        *clamped = true;
        return (int16_t)lim;
    }
    if (v < -lim) {
        *clamped = true;
        return (int16_t)-lim;
    }
    return v;
}

static void update_outputs(board_t *b)
{
    const bool braking = (b->flags & PROTO_FLAG_BRAKING) != 0;
    const bool stopped = (b->flags & (PROTO_FLAG_WATCHDOG | PROTO_FLAG_ESTOP)) != 0;
    const int16_t before[2] = {b->pwm_counts[0], b->pwm_counts[1]};
    for (int i = 0; i < 2; i++) {
        bool ignored = false;
        if (braking) {
            b->applied_e4nm[i] = clamp_torque(b->brake_e4nm[i], b->torque_limit_e4nm, &ignored);
        } else {
            b->applied_e4nm[i] =
                stopped ? 0 : clamp_torque(b->command_e4nm[i], b->torque_limit_e4nm, &ignored);
        }
        if (b->applied_e4nm[i] == 0) {
            b->pwm_counts[i] = 0;   /* zero torque = coast (H-bridge off), never a duty */
            continue;
        }
        const float torque_nm = (float)b->applied_e4nm[i] * 1e-4f;
        const float speed_radps = (float)b->vel_mradps[i] * 1e-3f;
        const float duty = motor_duty_from_coeffs(&b->coeffs, torque_nm, speed_radps);
        b->pwm_counts[i] = motor_duty_to_counts(duty, b->cfg.pwm_top);
    }
    if (before[0] != b->pwm_counts[0] || before[1] != b->pwm_counts[1]) {
        b->outputs_changed = true;
    }
}

/* ---- stop brake (docs/safety.md) ---------------------------------------------------------- */
static void brake_torques(board_t *b)
{
    const uint16_t bound = b->cfg.brake_limit_e4nm < b->torque_limit_e4nm ? b->cfg.brake_limit_e4nm
                                                                           : b->torque_limit_e4nm;
    for (int i = 0; i < 2; i++) {
        const float t = -b->cfg.brake_gain_e4nm_per_mradps * (float)b->vel_mradps[i];
        const float lim = (float)bound;
        const float c = t > lim ? lim : (t < -lim ? -lim : t);
        b->brake_e4nm[i] = (int16_t)(c >= 0.0f ? c + 0.5f : c - 0.5f);
    }
}

static void brake_start(board_t *b)
{
    b->brake_armed = false;
    b->flags |= PROTO_FLAG_BRAKING;
    b->brake_elapsed_us = 0;
    b->rest_elapsed_us = 0;
    b->rest_ref_ticks[0] = b->control_ticks[0];
    b->rest_ref_ticks[1] = b->control_ticks[1];
    b->brakes++;
    brake_torques(b);
}

static void brake_stop(board_t *b)
{
    b->flags &= (uint8_t)~PROTO_FLAG_BRAKING;
    b->brake_e4nm[0] = b->brake_e4nm[1] = 0;
}

/* one control step of the brake (velocities just measured) */
static void brake_step(board_t *b, uint32_t dt_us)
{
    if (!(b->flags & PROTO_FLAG_BRAKING)) {
        return;
    }
    b->brake_elapsed_us += dt_us;
    const int32_t d0 = b->control_ticks[0] - b->rest_ref_ticks[0];
    const int32_t d1 = b->control_ticks[1] - b->rest_ref_ticks[1];
    const float one_count = 1.5f * b->vel_factor;   /* mrad/s of 1.5 counts per period */
    const bool counting = (float)b->vel_mradps[0] > one_count || (float)b->vel_mradps[0] < -one_count ||
                          (float)b->vel_mradps[1] > one_count || (float)b->vel_mradps[1] < -one_count;
    if (d0 > 1 || d0 < -1 || d1 > 1 || d1 < -1 || counting) {   /* moved: restart the rest window */
        b->rest_ref_ticks[0] = b->control_ticks[0];
        b->rest_ref_ticks[1] = b->control_ticks[1];
        b->rest_elapsed_us = 0;
    } else {
        b->rest_elapsed_us += dt_us;
    }
    if (b->rest_elapsed_us >= (uint32_t)b->cfg.brake_rest_ms * 1000UL ||
        b->brake_elapsed_us >= (uint32_t)b->cfg.brake_max_ms * 1000UL) {
        brake_stop(b);   /* at rest (or out of time): H-bridge off */
        return;
    }
    brake_torques(b);
}

bool board_take_outputs_changed(board_t *b)
{
    const bool changed = b->outputs_changed;
    b->outputs_changed = false;
    return changed;
}

void board_init(board_t *b, const board_config_t *cfg, uint32_t now_ms, board_send_fn send,
                board_queued_fn queued, void *send_ctx)
{
    memset(b, 0, sizeof *b);
    b->cfg = *cfg;
    b->coeffs = motor_coeffs(&cfg->motor);
    b->outputs_changed = true;
    b->send = send;
    b->queued = queued;
    b->send_ctx = send_ctx;
    proto_decoder_init(&b->decoder, PROTO_VERSION);
    b->torque_limit_e4nm = cfg->hard_limit_e4nm;
    b->watchdog_ms = cfg->default_watchdog_ms;
    b->telemetry_period_ms = cfg->default_telemetry_period_ms;
    b->flags = PROTO_FLAG_WATCHDOG | PROTO_FLAG_RESET;
    b->boot_ms = now_ms;
    b->last_cmd_ms = now_ms;
    b->last_telemetry_ms = now_ms;
    b->next_status_ms = now_ms + BOARD_STATUS_PERIOD_MS;
    update_outputs(b);
}

static uint16_t clamp_u16(uint16_t v, uint16_t lo, uint16_t hi)
{
    return v < lo ? lo : (v > hi ? hi : v);
}

static void on_message(board_t *b, const proto_msg_t *m, uint32_t now_ms)
{
    if (b->have_rx_seq) {
        b->rx_gaps = (uint16_t)(b->rx_gaps + (uint8_t)(m->seq - b->last_rx_seq - 1u));
    }
    b->have_rx_seq = true;
    b->last_rx_seq = m->seq;
    proto_msg_t r;
    memset(&r, 0, sizeof r);
    switch (m->type) {
    case PROTO_HELLO:
        b->flags &= (uint8_t)~PROTO_FLAG_RESET;
        r.type = PROTO_HELLO_ACK;
        r.u.hello_ack.protocol_version = PROTO_VERSION;
        r.u.hello_ack.firmware_major = BOARD_FIRMWARE_MAJOR;
        r.u.hello_ack.firmware_minor = BOARD_FIRMWARE_MINOR;
        r.u.hello_ack.ticks_per_rev = b->cfg.ticks_per_rev;
        r.u.hello_ack.torque_limit_e4nm = b->torque_limit_e4nm;
        r.u.hello_ack.hard_torque_limit_e4nm = b->cfg.hard_limit_e4nm;
        r.u.hello_ack.watchdog_ms = b->watchdog_ms;
        r.u.hello_ack.telemetry_period_ms = b->telemetry_period_ms;
        /* a version-1 host reads only version-1 framing: it must still learn our version */
        send_msg_version(b, &r, m->u.hello.protocol_version == 1u ? PROTO_HANDSHAKE_FRAMING_VERSION
                                                                 : PROTO_VERSION);
        break;
    case PROTO_TORQUE_CMD: {
        b->cmd_seq = m->seq;
        b->last_cmd_ms = now_ms;
        b->flags &= (uint8_t)~PROTO_FLAG_WATCHDOG;
        brake_stop(b);   /* commands are back: they decide */
        b->brake_armed = true;
        bool clamped = false;
        b->command_e4nm[0] = clamp_torque(m->u.torque_cmd.left_e4nm, b->torque_limit_e4nm, &clamped);
        b->command_e4nm[1] = clamp_torque(m->u.torque_cmd.right_e4nm, b->torque_limit_e4nm, &clamped);
        if (b->flags & PROTO_FLAG_ESTOP) {
            b->command_e4nm[0] = b->command_e4nm[1] = 0;
        }
        if (clamped) {
            b->flags |= PROTO_FLAG_CLAMPED;
        } else {
            b->flags &= (uint8_t)~PROTO_FLAG_CLAMPED;
        }
        b->have_cmd = true;
        update_outputs(b);
        send_telemetry(b, now_ms);   /* the acknowledgement, echoing this command's seq */
        break;
    }
    case PROTO_STOP:
        /* the host has no torque to apply: brake to rest (once per stop), then release */
        b->cmd_seq = m->seq;
        b->last_cmd_ms = now_ms;
        b->flags &= (uint8_t)~(PROTO_FLAG_WATCHDOG | PROTO_FLAG_CLAMPED);
        b->command_e4nm[0] = b->command_e4nm[1] = 0;
        b->have_cmd = true;
        if (b->brake_armed && !(b->flags & PROTO_FLAG_ESTOP)) {
            brake_start(b);
        }
        update_outputs(b);
        send_telemetry(b, now_ms);
        break;
    case PROTO_HEARTBEAT:
        r.type = PROTO_HEARTBEAT;
        r.u.heartbeat = m->u.heartbeat;
        send_msg(b, &r);
        break;
    case PROTO_ESTOP:
        if (m->u.estop.engage) {
            b->flags |= PROTO_FLAG_ESTOP;
            brake_stop(b);
        } else {
            b->flags &= (uint8_t)~PROTO_FLAG_ESTOP;
        }
        b->command_e4nm[0] = b->command_e4nm[1] = 0;   /* release: 0 until the next command */
        update_outputs(b);
        break;
    case PROTO_CONFIG:
        b->torque_limit_e4nm = clamp_u16(m->u.config.torque_limit_e4nm, 0, b->cfg.hard_limit_e4nm);
        b->watchdog_ms = clamp_u16(m->u.config.watchdog_ms, BOARD_WATCHDOG_MIN_MS, BOARD_WATCHDOG_MAX_MS);
        b->telemetry_period_ms =
            clamp_u16(m->u.config.telemetry_period_ms, BOARD_TELEMETRY_MIN_MS, BOARD_TELEMETRY_MAX_MS);
        update_outputs(b);   /* re-clamps the applied torque to a lowered limit */
        r.type = PROTO_CONFIG_ACK;
        r.u.config.torque_limit_e4nm = b->torque_limit_e4nm;
        r.u.config.watchdog_ms = b->watchdog_ms;
        r.u.config.telemetry_period_ms = b->telemetry_period_ms;
        send_msg(b, &r);
        break;
    default:
        /* board -> host types arriving at the board: valid frames, nothing to do */
        break;
    }
}

void board_receive(board_t *b, uint8_t byte, uint32_t now_ms)
{
    proto_msg_t m;
    switch (proto_decoder_feed(&b->decoder, byte, &m)) {
    case PROTO_FEED_FRAME:
        on_message(b, &m, now_ms);
        break;
    case PROTO_FEED_REJECTED:
        b->flags |= PROTO_FLAG_RX_ERROR;
        /* negative acknowledgement, at most one per half telemetry period */
        if (!b->have_nack || now_ms - b->last_nack_ms >= (uint32_t)(b->telemetry_period_ms / 2u)) {
            b->have_nack = true;
            b->last_nack_ms = now_ms;
            send_telemetry(b, now_ms);
        }
        switch (b->decoder.last_reject) {
        case PROTO_REJECT_CRC:
            b->crc_errors++;
            break;
        case PROTO_REJECT_OVERSIZE:
        case PROTO_REJECT_COBS:
        case PROTO_REJECT_LENGTH:
            b->frame_errors++;
            break;
        default:
            b->type_errors++;
            break;
        }
        break;
    default:
        break;
    }
}

static int16_t velocity_mradps(board_t *b, int32_t dticks, uint32_t dt_us)
{
    if (dt_us == 0) {
        return 0;
    }
    if (dt_us != b->vel_dt_us) {   /* the period is constant: one division per change */
        /* 2 pi rad per revolution: vel = dticks * 2 pi / (ticks_per_rev * dt) in mrad/s */
        b->vel_factor = 6283185307.0f / ((float)b->cfg.ticks_per_rev * (float)dt_us);
        b->vel_dt_us = dt_us;
    }
    const float v = (float)dticks * b->vel_factor;
    if (v >= 32767.0f) {
        return 32767;
    }
    if (v <= -32768.0f) {
        return -32768;
    }
    return (int16_t)(v >= 0.0f ? v + 0.5f : v - 0.5f);
}

void board_control_step(board_t *b, int32_t left_ticks, int32_t right_ticks, uint32_t dt_us)
{
    b->vel_mradps[0] = velocity_mradps(b, left_ticks - b->control_ticks[0], dt_us);
    b->vel_mradps[1] = velocity_mradps(b, right_ticks - b->control_ticks[1], dt_us);
    b->control_ticks[0] = left_ticks;
    b->control_ticks[1] = right_ticks;
    brake_step(b, dt_us);
    update_outputs(b);
}

void board_encoders(board_t *b, int32_t left_ticks, int32_t right_ticks)
{
    b->ticks[0] = left_ticks;
    b->ticks[1] = right_ticks;
}

static bool due(uint32_t now_ms, uint32_t when_ms)
{
    return (int32_t)(now_ms - when_ms) >= 0;
}

void board_poll(board_t *b, uint32_t now_ms)
{
    if (!(b->flags & PROTO_FLAG_WATCHDOG) && now_ms - b->last_cmd_ms >= b->watchdog_ms) {
        b->flags |= PROTO_FLAG_WATCHDOG;
        b->watchdog_trips++;
        if (b->brake_armed && !(b->flags & PROTO_FLAG_ESTOP)) {
            brake_start(b);   /* a stop is a stop: brake the wheels to rest, then release */
        }
        update_outputs(b);
    }
    proto_msg_t m;
    const uint32_t period = b->telemetry_period_ms;
    const bool idle = !b->have_cmd || now_ms - b->last_cmd_ms >= 2u * period;
    if (!b->telemetry_pending && idle && now_ms - b->last_telemetry_ms >= period) {
        send_telemetry(b, now_ms);
    }
    if (due(now_ms, b->next_status_ms)) {
        b->next_status_ms += BOARD_STATUS_PERIOD_MS;
        if (due(now_ms, b->next_status_ms)) {
            b->next_status_ms = now_ms + BOARD_STATUS_PERIOD_MS;
        }
        memset(&m, 0, sizeof m);
        m.type = PROTO_STATUS;
        m.u.status.uptime_ms = now_ms - b->boot_ms;
        m.u.status.left_applied_e4nm = b->applied_e4nm[0];
        m.u.status.right_applied_e4nm = b->applied_e4nm[1];
        m.u.status.crc_errors = b->crc_errors;
        m.u.status.frame_errors = b->frame_errors;
        m.u.status.type_errors = b->type_errors;
        m.u.status.rx_gaps = b->rx_gaps;
        m.u.status.watchdog_trips = b->watchdog_trips;
        m.u.status.flags = b->flags;
        m.u.status.cmd_seq = b->cmd_seq;
        send_msg(b, &m);
    }
}

void board_service_tx(board_t *b, uint32_t now_ms)
{
    if (b->telemetry_pending && b->queued(b->send_ctx) < TELEMETRY_WIRE_BYTES) {
        send_telemetry(b, now_ms);
    }
}

void board_pwm(const board_t *b, int16_t *left_counts, int16_t *right_counts)
{
    *left_counts = b->pwm_counts[0];
    *right_counts = b->pwm_counts[1];
}
