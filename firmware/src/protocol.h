/*
 * protocol.h - the bridge <-> motor-board serial protocol (docs/serial-protocol.md), portable C99.
 *
 * No AVR headers and no I/O: the firmware and the host tests compile the same file.
 *
 * Wire format of one frame (protocol version 2):
 *     [0x00]  COBS( header(2) | body(n) | crc32c_le(4) )  0x00
 *     header byte 0 = (protocol_version << 4) | message_type, header byte 1 = sequence (uint8)
 * CRC-32C (Castagnoli: reflected poly 0x82F63B78, init and final XOR 0xFFFFFFFF) over header and
 * body, sent little-endian. The version nibble selects the check: version 1 frames carry a
 * CRC-16/CCITT-FALSE (2 bytes) instead; they are accepted only for HELLO / HELLO_ACK, so that a
 * version-1 peer learns about the mismatch. Every multi-byte field is a little-endian integer in
 * fixed point.
 */
#ifndef FW_PROTOCOL_H
#define FW_PROTOCOL_H

#include <stdbool.h>
#include <stdint.h>

#define PROTO_VERSION 2u
#define PROTO_HANDSHAKE_FRAMING_VERSION 1u   /* HELLO framing, and HELLO_ACK to a version-1 host */
#define PROTO_MAX_WIRE_BYTES 64u      /* both delimiters included */
#define PROTO_MAX_ENCODED_BYTES 62u   /* COBS block between delimiters */
#define PROTO_MAX_RAW_BYTES 61u       /* header + body + crc before COBS */
#define PROTO_HEADER_BYTES 2u
#define PROTO_CRC_BYTES 4u            /* CRC-32C; version-1 framing has 2 (CRC-16) */

/* status flag bits (TELEMETRY.flags, STATUS.flags) */
#define PROTO_FLAG_WATCHDOG 0x01u     /* no valid TORQUE_CMD for watchdog_ms: torque is zero */
#define PROTO_FLAG_CLAMPED 0x02u      /* the last TORQUE_CMD exceeded the limit and was clamped */
#define PROTO_FLAG_ESTOP 0x04u        /* emergency stop engaged: torque zero, commands ignored */
#define PROTO_FLAG_RX_ERROR 0x08u     /* a frame was rejected since the previous TELEMETRY */
#define PROTO_FLAG_RESET 0x10u        /* no HELLO received since boot */
#define PROTO_FLAG_BRAKING 0x20u      /* commands stopped: the wheels are braked to rest */
#define PROTO_FLAGS_DEFINED 0x3Fu

typedef enum {
    PROTO_HELLO = 0x1,
    PROTO_HELLO_ACK = 0x2,
    PROTO_TORQUE_CMD = 0x3,
    PROTO_TELEMETRY = 0x4,
    PROTO_STATUS = 0x5,
    PROTO_HEARTBEAT = 0x6,
    PROTO_ESTOP = 0x7,
    PROTO_CONFIG = 0x8,
    PROTO_CONFIG_ACK = 0x9,
    PROTO_STOP = 0xA                  /* version 2: brake to rest, then release */
} proto_type_t;

/* why a frame was rejected; the order is the order of REJECT_REASONS in the document */
typedef enum {
    PROTO_REJECT_OVERSIZE = 0,
    PROTO_REJECT_COBS,
    PROTO_REJECT_LENGTH,
    PROTO_REJECT_CRC,
    PROTO_REJECT_VERSION,
    PROTO_REJECT_TYPE,
    PROTO_REJECT_VALUE,
    PROTO_REJECT_COUNT,
    PROTO_OK = 0xFF
} proto_reject_t;

typedef struct {
    uint8_t protocol_version;
} proto_hello_t;

typedef struct {
    uint8_t protocol_version;
    uint8_t firmware_major;
    uint8_t firmware_minor;
    uint16_t ticks_per_rev;
    uint16_t torque_limit_e4nm;
    uint16_t hard_torque_limit_e4nm;
    uint16_t watchdog_ms;
    uint16_t telemetry_period_ms;
} proto_hello_ack_t;

typedef struct {
    int16_t left_e4nm;                /* wheel torque [1e-4 N m] */
    int16_t right_e4nm;
} proto_torque_cmd_t;

typedef struct {
    int16_t left_ticks;               /* encoder count modulo 2^16 */
    int16_t right_ticks;
    int16_t left_vel_mradps;          /* [1e-3 rad/s] */
    int16_t right_vel_mradps;
    uint8_t cmd_seq;                  /* sequence number of the last accepted TORQUE_CMD */
    uint8_t flags;
} proto_telemetry_t;

typedef struct {
    uint32_t uptime_ms;
    int16_t left_applied_e4nm;
    int16_t right_applied_e4nm;
    uint16_t crc_errors;
    uint16_t frame_errors;
    uint16_t type_errors;
    uint16_t rx_gaps;
    uint16_t watchdog_trips;
    uint8_t flags;
    uint8_t cmd_seq;
} proto_status_t;

typedef struct {
    uint32_t stamp_ms;
} proto_heartbeat_t;

typedef struct {
    uint8_t engage;                   /* 1 engage, 0 release */
} proto_estop_t;

typedef struct {
    uint16_t torque_limit_e4nm;
    uint16_t watchdog_ms;
    uint16_t telemetry_period_ms;
} proto_config_t;                     /* CONFIG and CONFIG_ACK share the layout */

#define PROTO_STOP_REASON_MAX 2u      /* 0 unspecified, 1 input stale, 2 host shutdown */

typedef struct {
    uint8_t reason;
} proto_stop_t;

typedef struct {
    uint8_t type;                     /* proto_type_t */
    uint8_t version;                  /* protocol version in the header */
    uint8_t seq;                      /* sender's sequence number */
    union {
        proto_hello_t hello;
        proto_hello_ack_t hello_ack;
        proto_torque_cmd_t torque_cmd;
        proto_telemetry_t telemetry;
        proto_status_t status;
        proto_heartbeat_t heartbeat;
        proto_estop_t estop;
        proto_config_t config;        /* also CONFIG_ACK */
        proto_stop_t stop;
    } u;
} proto_msg_t;

/* Body length in bytes of a message type, 0 for an unknown type. */
uint8_t proto_body_bytes(uint8_t type);

/* CRC-16/CCITT-FALSE of data, continuing `crc` (start with 0xFFFF). */
uint16_t proto_crc16(const uint8_t *data, uint16_t len, uint16_t crc);

/* CRC-32C of data (complete: initial value and final XOR applied). */
uint32_t proto_crc32c(const uint8_t *data, uint16_t len);

/* Bytes of the check value of a frame of `version`: 2 for version 1, 4 after. */
uint8_t proto_check_bytes(uint8_t version);

/* COBS-encode `len` bytes into `out` (room for len + len / 254 + 1); returns the output length. */
uint16_t proto_cobs_encode(const uint8_t *in, uint16_t len, uint8_t *out);

/* Strict COBS decode of one block (no delimiter); returns the length, or -1 when invalid
 * (empty, contains 0x00, a code byte runs past the end, or the output exceeds `cap`). */
int16_t proto_cobs_decode(const uint8_t *in, uint16_t len, uint8_t *out, uint16_t cap);

/* Wire bytes of one message: [0x00] COBS(header | body | crc) 0x00. Returns the length written,
 * 0 when `cap` is too small or the type is unknown. */
uint16_t proto_encode(const proto_msg_t *msg, bool leading_delimiter, uint8_t *out, uint16_t cap);

/* Check and parse one de-COBSed frame (header | body | crc). Returns PROTO_OK and fills `out`,
 * or the rejection reason. */
proto_reject_t proto_decode_raw(const uint8_t *raw, uint16_t len, uint8_t accepted_version,
                                proto_msg_t *out);

/* Incremental decoder, one byte at a time (from the UART receive path). */
typedef struct {
    uint8_t buf[PROTO_MAX_ENCODED_BYTES];
    uint8_t len;
    bool discarding;
    uint8_t accepted_version;
    uint8_t last_reject;              /* proto_reject_t of the last rejection */
    uint16_t accepted;                /* wrapping counters */
    uint16_t rejected[PROTO_REJECT_COUNT];
} proto_decoder_t;

typedef enum {
    PROTO_FEED_NONE = 0,              /* byte consumed, no frame ended */
    PROTO_FEED_FRAME,                 /* a valid frame ended: *out is filled */
    PROTO_FEED_REJECTED               /* a frame ended and was rejected: see last_reject */
} proto_feed_t;

void proto_decoder_init(proto_decoder_t *d, uint8_t accepted_version);
proto_feed_t proto_decoder_feed(proto_decoder_t *d, uint8_t byte, proto_msg_t *out);

#endif /* FW_PROTOCOL_H */
