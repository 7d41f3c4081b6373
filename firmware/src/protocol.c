/* protocol.c - framing, CRC and message layouts of docs/serial-protocol.md; see protocol.h. */
#include "protocol.h"

#include <string.h>

uint8_t proto_body_bytes(uint8_t type)
{
    switch (type) {
    case PROTO_HELLO: return 1;
    case PROTO_HELLO_ACK: return 13;
    case PROTO_TORQUE_CMD: return 4;
    case PROTO_TELEMETRY: return 10;
    case PROTO_STATUS: return 20;
    case PROTO_HEARTBEAT: return 4;
    case PROTO_ESTOP: return 1;
    case PROTO_CONFIG: return 6;
    case PROTO_CONFIG_ACK: return 6;
    case PROTO_STOP: return 1;
    default: return 0;
    }
}

/* ---- CRC-16/CCITT-FALSE: nibble table (32 bytes) keeps Flash small and is ~2x bitwise speed */
static const uint16_t CRC_NIBBLE[16] = {
    0x0000, 0x1021, 0x2042, 0x3063, 0x4084, 0x50A5, 0x60C6, 0x70E7,
    0x8108, 0x9129, 0xA14A, 0xB16B, 0xC18C, 0xD1AD, 0xE1CE, 0xF1EF};

uint16_t proto_crc16(const uint8_t *data, uint16_t len, uint16_t crc)
{
    for (uint16_t i = 0; i < len; i++) {
        crc ^= (uint16_t)data[i] << 8;
        crc = (uint16_t)((crc << 4) ^ CRC_NIBBLE[crc >> 12]);
        crc = (uint16_t)((crc << 4) ^ CRC_NIBBLE[crc >> 12]);
    }
    return crc;
}

/* ---- CRC-32C (Castagnoli), reflected: nibble table (64 bytes), two steps per byte --------- */
static const uint32_t CRC32C_NIBBLE[16] = {
    0x00000000UL, 0x105EC76FUL, 0x20BD8EDEUL, 0x30E349B1UL, 0x417B1DBCUL, 0x5125DAD3UL,
    0x61C69362UL, 0x7198540DUL, 0x82F63B78UL, 0x92A8FC17UL, 0xA24BB5A6UL, 0xB21572C9UL,
    0xC38D26C4UL, 0xD3D3E1ABUL, 0xE330A81AUL, 0xF36E6F75UL};

uint32_t proto_crc32c(const uint8_t *data, uint16_t len)
{
    uint32_t crc = 0xFFFFFFFFUL;
    for (uint16_t i = 0; i < len; i++) {
        crc ^= data[i];
        crc = (crc >> 4) ^ CRC32C_NIBBLE[crc & 0x0Fu];
        crc = (crc >> 4) ^ CRC32C_NIBBLE[crc & 0x0Fu];
    }
    return crc ^ 0xFFFFFFFFUL;
}

uint8_t proto_check_bytes(uint8_t version)
{
    return version == 1u ? 2u : 4u;
}

/* appends the check value of `version` at raw + n; returns its length */
static uint8_t put_check(uint8_t *raw, uint16_t n, uint8_t version)
{
    if (version == 1u) {
        const uint16_t c = proto_crc16(raw, n, 0xFFFF);
        raw[n] = (uint8_t)c;
        raw[n + 1] = (uint8_t)(c >> 8);
        return 2u;
    }
    const uint32_t c = proto_crc32c(raw, n);
    for (uint8_t k = 0; k < 4u; k++) {
        raw[n + k] = (uint8_t)(c >> (8u * k));
    }
    return 4u;
}

/* ---- COBS -------------------------------------------------------------------------------- */
uint16_t proto_cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out)
{
    uint16_t code_index = 0;
    uint16_t n = 1;
    uint8_t code = 1;
    for (uint16_t i = 0; i < len; i++) {
        if (in[i] == 0) {
            out[code_index] = code;
            code_index = n++;
            code = 1;
        } else {
            out[n++] = in[i];
            code++;
            if (code == 0xFF) {
                out[code_index] = code;
                code_index = n++;
                code = 1;
            }
        }
    }
    out[code_index] = code;
    return n;
}

int16_t proto_cobs_decode(const uint8_t *in, uint16_t len, uint8_t *out, uint16_t cap)
{
    if (len == 0) {
        return -1;
    }
    uint16_t i = 0;
    uint16_t n = 0;
    while (i < len) {
        const uint8_t code = in[i];
        if (code == 0) {
            return -1;
        }
        const uint16_t end = (uint16_t)(i + code);
        if (end > len) {
            return -1;
        }
        for (uint16_t j = (uint16_t)(i + 1); j < end; j++) {
            if (in[j] == 0 || n >= cap) {
                return -1;
            }
            out[n++] = in[j];
        }
        i = end;
        if (code != 0xFF && i < len) {
            if (n >= cap) {
                return -1;
            }
            out[n++] = 0;
        }
    }
    return (int16_t)n;
}

/* ---- little-endian field access ------------------------------------------------------------ */
static uint8_t *put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    return p + 2;
}

static uint8_t *put_u32(uint8_t *p, uint32_t v)
{
    p = put_u16(p, (uint16_t)v);
    return put_u16(p, (uint16_t)(v >> 16));
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
}

static uint32_t get_u32(const uint8_t *p)
{
    return get_u16(p) | ((uint32_t)get_u16(p + 2) << 16);
}

/* body bytes of `msg` into p; returns the end pointer */
static uint8_t *pack_body(const proto_msg_t *m, uint8_t *p)
{
    switch (m->type) {
    case PROTO_HELLO:
        *p++ = m->u.hello.protocol_version;
        break;
    case PROTO_HELLO_ACK:
        *p++ = m->u.hello_ack.protocol_version;
        *p++ = m->u.hello_ack.firmware_major;
        *p++ = m->u.hello_ack.firmware_minor;
        p = put_u16(p, m->u.hello_ack.ticks_per_rev);
        p = put_u16(p, m->u.hello_ack.torque_limit_e4nm);
        p = put_u16(p, m->u.hello_ack.hard_torque_limit_e4nm);
        p = put_u16(p, m->u.hello_ack.watchdog_ms);
        p = put_u16(p, m->u.hello_ack.telemetry_period_ms);
        break;
    case PROTO_TORQUE_CMD:
        p = put_u16(p, (uint16_t)m->u.torque_cmd.left_e4nm);
        p = put_u16(p, (uint16_t)m->u.torque_cmd.right_e4nm);
        break;
    case PROTO_TELEMETRY:
        p = put_u16(p, (uint16_t)m->u.telemetry.left_ticks);
        p = put_u16(p, (uint16_t)m->u.telemetry.right_ticks);
        p = put_u16(p, (uint16_t)m->u.telemetry.left_vel_mradps);
        p = put_u16(p, (uint16_t)m->u.telemetry.right_vel_mradps);
        *p++ = m->u.telemetry.cmd_seq;
        *p++ = m->u.telemetry.flags;
        break;
    case PROTO_STATUS:
        p = put_u32(p, m->u.status.uptime_ms);
        p = put_u16(p, (uint16_t)m->u.status.left_applied_e4nm);
        p = put_u16(p, (uint16_t)m->u.status.right_applied_e4nm);
        p = put_u16(p, m->u.status.crc_errors);
        p = put_u16(p, m->u.status.frame_errors);
        p = put_u16(p, m->u.status.type_errors);
        p = put_u16(p, m->u.status.rx_gaps);
        p = put_u16(p, m->u.status.watchdog_trips);
        *p++ = m->u.status.flags;
        *p++ = m->u.status.cmd_seq;
        break;
    case PROTO_HEARTBEAT:
        p = put_u32(p, m->u.heartbeat.stamp_ms);
        break;
    case PROTO_ESTOP:
        *p++ = m->u.estop.engage;
        break;
    case PROTO_STOP:
        *p++ = m->u.stop.reason;
        break;
    case PROTO_CONFIG:
    case PROTO_CONFIG_ACK:
        p = put_u16(p, m->u.config.torque_limit_e4nm);
        p = put_u16(p, m->u.config.watchdog_ms);
        p = put_u16(p, m->u.config.telemetry_period_ms);
        break;
    default:
        break;
    }
    return p;
}

/* parse the body (length already checked); returns false when a value is invalid */
static bool unpack_body(const uint8_t *p, proto_msg_t *m)
{
    switch (m->type) {
    case PROTO_HELLO:
        m->u.hello.protocol_version = p[0];
        return p[0] != 0;
    case PROTO_HELLO_ACK:
        m->u.hello_ack.protocol_version = p[0];
        m->u.hello_ack.firmware_major = p[1];
        m->u.hello_ack.firmware_minor = p[2];
        m->u.hello_ack.ticks_per_rev = get_u16(p + 3);
        m->u.hello_ack.torque_limit_e4nm = get_u16(p + 5);
        m->u.hello_ack.hard_torque_limit_e4nm = get_u16(p + 7);
        m->u.hello_ack.watchdog_ms = get_u16(p + 9);
        m->u.hello_ack.telemetry_period_ms = get_u16(p + 11);
        return m->u.hello_ack.protocol_version != 0 && m->u.hello_ack.ticks_per_rev != 0 &&
               m->u.hello_ack.telemetry_period_ms != 0;
    case PROTO_TORQUE_CMD:
        m->u.torque_cmd.left_e4nm = (int16_t)get_u16(p);
        m->u.torque_cmd.right_e4nm = (int16_t)get_u16(p + 2);
        return true;
    case PROTO_TELEMETRY:
        m->u.telemetry.left_ticks = (int16_t)get_u16(p);
        m->u.telemetry.right_ticks = (int16_t)get_u16(p + 2);
        m->u.telemetry.left_vel_mradps = (int16_t)get_u16(p + 4);
        m->u.telemetry.right_vel_mradps = (int16_t)get_u16(p + 6);
        m->u.telemetry.cmd_seq = p[8];
        m->u.telemetry.flags = p[9];
        return (p[9] & (uint8_t)~PROTO_FLAGS_DEFINED) == 0;
    case PROTO_STATUS:
        m->u.status.uptime_ms = get_u32(p);
        m->u.status.left_applied_e4nm = (int16_t)get_u16(p + 4);
        m->u.status.right_applied_e4nm = (int16_t)get_u16(p + 6);
        m->u.status.crc_errors = get_u16(p + 8);
        m->u.status.frame_errors = get_u16(p + 10);
        m->u.status.type_errors = get_u16(p + 12);
        m->u.status.rx_gaps = get_u16(p + 14);
        m->u.status.watchdog_trips = get_u16(p + 16);
        m->u.status.flags = p[18];
        m->u.status.cmd_seq = p[19];
        return (p[18] & (uint8_t)~PROTO_FLAGS_DEFINED) == 0;
    case PROTO_HEARTBEAT:
        m->u.heartbeat.stamp_ms = get_u32(p);
        return true;
    case PROTO_ESTOP:
        m->u.estop.engage = p[0];
        return p[0] <= 1;
    case PROTO_STOP:
        m->u.stop.reason = p[0];
        return p[0] <= PROTO_STOP_REASON_MAX;
    case PROTO_CONFIG:
    case PROTO_CONFIG_ACK:
        m->u.config.torque_limit_e4nm = get_u16(p);
        m->u.config.watchdog_ms = get_u16(p + 2);
        m->u.config.telemetry_period_ms = get_u16(p + 4);
        return true;
    default:
        return false;
    }
}

uint16_t proto_encode(const proto_msg_t *msg, bool leading_delimiter, uint8_t *out, uint16_t cap)
{
    const uint8_t body = proto_body_bytes(msg->type);
    if (body == 0) {
        return 0;
    }
    uint8_t raw[PROTO_MAX_RAW_BYTES];
    raw[0] = (uint8_t)((msg->version << 4) | (msg->type & 0x0F));
    raw[1] = msg->seq;
    uint8_t *end = pack_body(msg, raw + PROTO_HEADER_BYTES);
    const uint16_t n = (uint16_t)(end - raw);
    const uint16_t raw_len = (uint16_t)(n + put_check(raw, n, msg->version));
    const uint16_t need = (uint16_t)(raw_len + raw_len / 254u + 2u + (leading_delimiter ? 1u : 0u));
    if (need > cap) {
        return 0;
    }
    uint16_t pos = 0;
    if (leading_delimiter) {
        out[pos++] = 0x00;
    }
    pos = (uint16_t)(pos + proto_cobs_encode(raw, raw_len, out + pos));
    out[pos++] = 0x00;
    return pos;
}

proto_reject_t proto_decode_raw(const uint8_t *raw, uint16_t len, uint8_t accepted_version,
                                proto_msg_t *out)
{
    if (len < PROTO_HEADER_BYTES + 1u + 2u) {
        return PROTO_REJECT_LENGTH;
    }
    const uint8_t version = (uint8_t)(raw[0] >> 4);
    const uint8_t check = proto_check_bytes(version);
    if (len < PROTO_HEADER_BYTES + 1u + check) {
        return PROTO_REJECT_LENGTH;
    }
    const uint16_t n = (uint16_t)(len - check);
    if (check == 2u) {
        if (proto_crc16(raw, n, 0xFFFF) != get_u16(raw + n)) {
            return PROTO_REJECT_CRC;
        }
    } else if (proto_crc32c(raw, n) != get_u32(raw + n)) {
        return PROTO_REJECT_CRC;
    }
    const uint8_t type = (uint8_t)(raw[0] & 0x0F);
    const uint8_t body = proto_body_bytes(type);
    if (body == 0) {
        return PROTO_REJECT_TYPE;
    }
    const bool version_free = type == PROTO_HELLO || type == PROTO_HELLO_ACK;
    if (version == 0 || (version != accepted_version && !version_free)) {
        return PROTO_REJECT_VERSION;
    }
    if (len != (uint16_t)(PROTO_HEADER_BYTES + body + check)) {
        return PROTO_REJECT_LENGTH;
    }
    out->type = type;
    out->version = version;
    out->seq = raw[1];
    if (!unpack_body(raw + PROTO_HEADER_BYTES, out)) {
        return PROTO_REJECT_VALUE;
    }
    return PROTO_OK;
}

void proto_decoder_init(proto_decoder_t *d, uint8_t accepted_version)
{
    memset(d, 0, sizeof *d);
    d->accepted_version = accepted_version;
    d->last_reject = PROTO_OK;
}

static proto_feed_t reject(proto_decoder_t *d, proto_reject_t reason)
{
    d->rejected[reason]++;
    d->last_reject = (uint8_t)reason;
    return PROTO_FEED_REJECTED;
}

proto_feed_t proto_decoder_feed(proto_decoder_t *d, uint8_t byte, proto_msg_t *out)
{
    if (byte != 0x00) {
        if (d->discarding) {
            return PROTO_FEED_NONE;
        }
        if (d->len >= PROTO_MAX_ENCODED_BYTES) {
            d->len = 0;
            d->discarding = true;
            return reject(d, PROTO_REJECT_OVERSIZE);
        }
        d->buf[d->len++] = byte;
        return PROTO_FEED_NONE;
    }
    /* delimiter */
    const uint8_t n = d->len;
    d->len = 0;
    d->discarding = false;
    if (n == 0) {
        return PROTO_FEED_NONE;   /* empty frame between two delimiters: ignored */
    }
    uint8_t raw[PROTO_MAX_ENCODED_BYTES];
    const int16_t raw_len = proto_cobs_decode(d->buf, n, raw, sizeof raw);
    if (raw_len < 0) {
        return reject(d, PROTO_REJECT_COBS);
    }
    const proto_reject_t r = proto_decode_raw(raw, (uint16_t)raw_len, d->accepted_version, out);
    if (r != PROTO_OK) {
        return reject(d, r);
    }
    d->accepted++;
    return PROTO_FEED_FRAME;
}
