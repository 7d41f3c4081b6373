/*
 * protocol_vectors.c - host-side driver of the firmware's src/protocol.c for the vector tests
 * (test/test_firmware.py feeds it docs/serial-protocol-vectors.json, one command per line).
 *
 * Commands on stdin, answers on stdout (one line each unless stated):
 *   D <hex>        feed the bytes to a fresh incremental decoder; prints one line per decoded
 *                  frame "F <TYPE> version=<v> seq=<s> <field>=<value> ...", then
 *                  "R <reason>=<count> ..." (non-zero counters only) and "END"
 *   E <TYPE> <version> <seq> <leading 0|1> <field>=<value> ...
 *                  encode; prints "H <hex>" (or "ERR ..." on a bad field)
 *   C <hex>        prints "C <crc16 of the bytes as 0x....>"
 *   K <hex>        prints "K <crc32c of the bytes as 0x........>"
 *   X <hex>        COBS-decode one block; prints "X <hex>" or "X invalid"
 * Field and type names are those of the document (and of
 * ament_formation.core.serial.serial_protocol).
 */
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "protocol.h"

typedef enum { U8, U16, I16, U32 } kind_t;

typedef struct {
    const char *name;
    kind_t kind;
    size_t offset;
} field_t;

typedef struct {
    const char *name;
    uint8_t type;
    const field_t *fields;
    int n_fields;
} type_desc_t;

#define F(msgfield, name, kind) {name, kind, offsetof(proto_msg_t, u.msgfield)}

static const field_t HELLO_F[] = {F(hello.protocol_version, "protocol_version", U8)};
static const field_t HELLO_ACK_F[] = {
    F(hello_ack.protocol_version, "protocol_version", U8),
    F(hello_ack.firmware_major, "firmware_major", U8),
    F(hello_ack.firmware_minor, "firmware_minor", U8),
    F(hello_ack.ticks_per_rev, "ticks_per_rev", U16),
    F(hello_ack.torque_limit_e4nm, "torque_limit_e4nm", U16),
    F(hello_ack.hard_torque_limit_e4nm, "hard_torque_limit_e4nm", U16),
    F(hello_ack.watchdog_ms, "watchdog_ms", U16),
    F(hello_ack.telemetry_period_ms, "telemetry_period_ms", U16)};
static const field_t TORQUE_F[] = {F(torque_cmd.left_e4nm, "left_e4nm", I16),
                                   F(torque_cmd.right_e4nm, "right_e4nm", I16)};
static const field_t TELEMETRY_F[] = {
    F(telemetry.left_ticks, "left_ticks", I16), F(telemetry.right_ticks, "right_ticks", I16),
    F(telemetry.left_vel_mradps, "left_vel_mradps", I16),
    F(telemetry.right_vel_mradps, "right_vel_mradps", I16),
    F(telemetry.cmd_seq, "cmd_seq", U8), F(telemetry.flags, "flags", U8)};
static const field_t STATUS_F[] = {
    F(status.uptime_ms, "uptime_ms", U32),
    F(status.left_applied_e4nm, "left_applied_e4nm", I16),
    F(status.right_applied_e4nm, "right_applied_e4nm", I16),
    F(status.crc_errors, "crc_errors", U16), F(status.frame_errors, "frame_errors", U16),
    F(status.type_errors, "type_errors", U16), F(status.rx_gaps, "rx_gaps", U16),
    F(status.watchdog_trips, "watchdog_trips", U16), F(status.flags, "flags", U8),
    F(status.cmd_seq, "cmd_seq", U8)};
static const field_t HEARTBEAT_F[] = {F(heartbeat.stamp_ms, "stamp_ms", U32)};
static const field_t ESTOP_F[] = {F(estop.engage, "engage", U8)};
static const field_t STOP_F[] = {F(stop.reason, "reason", U8)};
static const field_t CONFIG_F[] = {F(config.torque_limit_e4nm, "torque_limit_e4nm", U16),
                                   F(config.watchdog_ms, "watchdog_ms", U16),
                                   F(config.telemetry_period_ms, "telemetry_period_ms", U16)};

#define T(name, type, f) {name, type, f, (int)(sizeof f / sizeof f[0])}
static const type_desc_t TYPES[] = {
    T("HELLO", PROTO_HELLO, HELLO_F),           T("HELLO_ACK", PROTO_HELLO_ACK, HELLO_ACK_F),
    T("TORQUE_CMD", PROTO_TORQUE_CMD, TORQUE_F), T("TELEMETRY", PROTO_TELEMETRY, TELEMETRY_F),
    T("STATUS", PROTO_STATUS, STATUS_F),         T("HEARTBEAT", PROTO_HEARTBEAT, HEARTBEAT_F),
    T("ESTOP", PROTO_ESTOP, ESTOP_F),            T("CONFIG", PROTO_CONFIG, CONFIG_F),
    T("CONFIG_ACK", PROTO_CONFIG_ACK, CONFIG_F), T("STOP", PROTO_STOP, STOP_F)};
#define N_TYPES ((int)(sizeof TYPES / sizeof TYPES[0]))

static const char *const REASONS[PROTO_REJECT_COUNT] = {"oversize", "cobs", "length", "crc",
                                                        "version", "type", "value"};

static const type_desc_t *type_by_code(uint8_t t)
{
    for (int i = 0; i < N_TYPES; i++) {
        if (TYPES[i].type == t) {
            return &TYPES[i];
        }
    }
    return NULL;
}

static const type_desc_t *type_by_name(const char *name)
{
    for (int i = 0; i < N_TYPES; i++) {
        if (!strcmp(TYPES[i].name, name)) {
            return &TYPES[i];
        }
    }
    return NULL;
}

static long long get_field(const proto_msg_t *m, const field_t *f)
{
    const char *p = (const char *)m + f->offset;
    switch (f->kind) {
    case U8: return *(const uint8_t *)p;
    case U16: return *(const uint16_t *)p;
    case I16: return *(const int16_t *)p;
    case U32: return *(const uint32_t *)p;
    }
    return 0;
}

static int set_field(proto_msg_t *m, const field_t *f, long long v)
{
    char *p = (char *)m + f->offset;
    switch (f->kind) {
    case U8:
        if (v < 0 || v > 0xFF) return -1;
        *(uint8_t *)p = (uint8_t)v;
        return 0;
    case U16:
        if (v < 0 || v > 0xFFFF) return -1;
        *(uint16_t *)p = (uint16_t)v;
        return 0;
    case I16:
        if (v < -32768 || v > 32767) return -1;
        *(int16_t *)p = (int16_t)v;
        return 0;
    case U32:
        if (v < 0 || v > 0xFFFFFFFFLL) return -1;
        *(uint32_t *)p = (uint32_t)v;
        return 0;
    }
    return -1;
}

static size_t parse_hex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = 0;
    while (s[0] && s[1] && s[0] != '\n' && n < cap) {
        char b[3] = {s[0], s[1], 0};
        out[n++] = (uint8_t)strtoul(b, NULL, 16);
        s += 2;
    }
    return n;
}

static void print_hex(const uint8_t *b, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        printf("%02x", b[i]);
    }
}

static void cmd_decode(const char *hex)
{
    static uint8_t bytes[1 << 16];
    const size_t n = parse_hex(hex, bytes, sizeof bytes);
    proto_decoder_t d;
    proto_decoder_init(&d, PROTO_VERSION);
    for (size_t i = 0; i < n; i++) {
        proto_msg_t m;
        if (proto_decoder_feed(&d, bytes[i], &m) == PROTO_FEED_FRAME) {
            const type_desc_t *t = type_by_code(m.type);
            printf("F %s version=%u seq=%u", t ? t->name : "?", m.version, m.seq);
            for (int k = 0; t && k < t->n_fields; k++) {
                printf(" %s=%lld", t->fields[k].name, get_field(&m, &t->fields[k]));
            }
            printf("\n");
        }
    }
    printf("R");
    for (int r = 0; r < PROTO_REJECT_COUNT; r++) {
        if (d.rejected[r]) {
            printf(" %s=%u", REASONS[r], d.rejected[r]);
        }
    }
    printf("\nEND\n");
}

static void cmd_encode(char *args)
{
    char *save = NULL;
    const char *tname = strtok_r(args, " \n", &save);
    const char *version = strtok_r(NULL, " \n", &save);
    const char *seq = strtok_r(NULL, " \n", &save);
    const char *leading = strtok_r(NULL, " \n", &save);
    const type_desc_t *t = tname ? type_by_name(tname) : NULL;
    if (!t || !version || !seq || !leading) {
        printf("ERR usage: E TYPE VERSION SEQ LEADING FIELD=VALUE...\n");
        return;
    }
    proto_msg_t m;
    memset(&m, 0, sizeof m);
    m.type = t->type;
    m.version = (uint8_t)atoi(version);
    m.seq = (uint8_t)atoi(seq);
    int set = 0;
    for (char *tok = strtok_r(NULL, " \n", &save); tok; tok = strtok_r(NULL, " \n", &save)) {
        char *eq = strchr(tok, '=');
        if (!eq) {
            printf("ERR %s: expected FIELD=VALUE\n", tok);
            return;
        }
        *eq = 0;
        int found = 0;
        for (int k = 0; k < t->n_fields; k++) {
            if (!strcmp(t->fields[k].name, tok)) {
                if (set_field(&m, &t->fields[k], atoll(eq + 1)) != 0) {
                    printf("ERR %s: value out of range\n", tok);
                    return;
                }
                found = 1;
                set++;
            }
        }
        if (!found) {
            printf("ERR %s: no such field in %s\n", tok, t->name);
            return;
        }
    }
    if (set != t->n_fields) {
        printf("ERR %s: %d of %d fields given\n", t->name, set, t->n_fields);
        return;
    }
    uint8_t out[PROTO_MAX_WIRE_BYTES];
    const uint16_t n = proto_encode(&m, atoi(leading) != 0, out, sizeof out);
    if (n == 0) {
        printf("ERR encode failed\n");
        return;
    }
    printf("H ");
    print_hex(out, n);
    printf("\n");
}

int main(void)
{
    static char line[1 << 18];
    static uint8_t buf[1 << 16];
    while (fgets(line, sizeof line, stdin)) {
        if (line[0] == 'D' && line[1] == ' ') {
            cmd_decode(line + 2);
        } else if (line[0] == 'E' && line[1] == ' ') {
            cmd_encode(line + 2);
        } else if (line[0] == 'C' && line[1] == ' ') {
            const size_t n = parse_hex(line + 2, buf, sizeof buf);
            printf("C 0x%04x\n", proto_crc16(buf, (uint16_t)n, 0xFFFF));
        } else if (line[0] == 'K' && line[1] == ' ') {
            const size_t n = parse_hex(line + 2, buf, sizeof buf);
            printf("K 0x%08lx\n", (unsigned long)proto_crc32c(buf, (uint16_t)n));
        } else if (line[0] == 'X' && line[1] == ' ') {
            const size_t n = parse_hex(line + 2, buf, sizeof buf);
            static uint8_t out[30000];
            const int16_t m = proto_cobs_decode(buf, (uint16_t)n, out, sizeof out);
            if (m < 0) {
                printf("X invalid\n");
            } else {
                printf("X ");
                print_hex(out, (size_t)m);
                printf("\n");
            }
        } else if (line[0] != '\n' && line[0] != 0) {
            printf("ERR unknown command\n");
        }
        fflush(stdout);
    }
    return 0;
}
