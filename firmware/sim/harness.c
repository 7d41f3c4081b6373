/*
 * harness.c - run the motor-board firmware ELF in simavr, with the UART on a pty, emulated
 * quadrature encoders driven by a wheel model fed from the PWM outputs, and cycle measurements.
 *
 * Usage: formation_fw_sim FIRMWARE.elf [--status FILE] [--link PATH] [--duration-s S]
 *                                      [--no-realtime] [--freeze-wheels] [--control FILE]
 *                                      [--reverse-motor left|right] [--reverse-encoder left|right]
 *                                      [--kt-scale L,R]
 *
 *   stdout, first line:  "PTY /dev/pts/N"  (the slave side: open it like a serial port)
 *   --status FILE        one JSON object per line every 10 ms of emulated time (see emit_status)
 *   --link PATH          also create a symlink PATH -> pty slave (removed at exit)
 *   --duration-s S       stop after S seconds of emulated time (default: run until SIGTERM/SIGINT)
 *   --no-realtime        run as fast as the host can (default: paced to the wall clock)
 *   --freeze-wheels      hold the wheels still (encoders never move)
 *   --control FILE       fault injection on the host -> board line, read every 10 ms of emulated
 *                        time: "pass" (default), "cut" (every byte dropped: a cut cable) or
 *                        "corrupt" (one bit flipped in the first data byte of every frame)
 *   --reverse-motor W    wheel W's motor wired reversed: a positive duty turns it backward
 *   --reverse-encoder W  wheel W's encoder wired reversed (A and B swapped): counts down forward
 *   --kt-scale L,R       the real motors' torque constants over config.h's (a wrong motor):
 *                        what `formation board-check` finds (repeatable --reverse-* options)
 *
 * Measurements (cycles of the emulated 16 MHz CPU):
 *   isr: per vector, count and worst case from vector entry to RETI (the simavr "interrupt
 *        running" IRQ); the firmware never nests interrupts.
 *   loop: the firmware writes GPIOR0 = 1 when its main loop starts work and 0 just before it
 *        sleeps; the worst busy stretch is reported with ISR preemption included ("loop_max")
 *        and with ISR cycles subtracted ("loop_max_own").
 *   host -> board line: "last_frame_rx_t_s" is when the firmware's RX interrupt read the 0x00
 *        that ended the last complete frame fed to it (the n-th RX interrupt reads the n-th byte);
 *        "pwm_change_t_s" is when either PWM output last changed (sampled every 100 us).
 *   board -> host line: decoded with the firmware's own src/protocol.c; TELEMETRY frames are
 *        counted with their emulated time (rate in emulated time), the last TELEMETRY and STATUS
 *        fields are reported (error counters, flags, applied torque).
 *
 * Wheel model (per wheel, identical unless wired otherwise): J domega/dt = tau(duty, omega) - b omega, with
 * tau from the same DC-motor model and constants as the firmware (src/motor_model.c,
 * src/config.h), integrated every 100 us of emulated time; encoder A/B edges are emitted one
 * quadrature step at a time (at most one per wheel per 100 us step: up to 43 rad/s, twice the motor's no-load speed).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pty.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_interrupts.h>
#include <sim_io.h>
#include <sim_irq.h>
#include <sim_cycle_timers.h>
#include <sim_time.h>
#include <avr_ioport.h>
#include <avr_uart.h>

#include "../src/config.h"
#include "../src/motor_model.h"
#include "../src/protocol.h"

/* ATmega328P data-space addresses (datasheet, register summary) */
#define REG_PORTB 0x25
#define REG_DDRB 0x24
#define REG_GPIOR0 0x3E
#define REG_WDTCSR 0x60
#define REG_TCCR1A 0x80
#define REG_ICR1L 0x86
#define REG_OCR1AL 0x88
#define REG_OCR1BL 0x8A
#define COM1A1_BIT 7
#define COM1B1_BIT 5

#define MODEL_STEP_US 100u
#define IO_POLL_STEPS 2u            /* pty polled every 200 us of emulated time */
#define STATUS_PERIOD_US 10000u
#define N_VECTORS 26
#define VECTOR_USART_RX 18
#define IN_BUF_BYTES 8192u
#define OUT_BUF_BYTES 8192u

static const char *const VECTOR_NAMES[N_VECTORS] = {
    "RESET", "INT0", "INT1", "PCINT0", "PCINT1", "PCINT2", "WDT", "TIMER2_COMPA", "TIMER2_COMPB",
    "TIMER2_OVF", "TIMER1_CAPT", "TIMER1_COMPA", "TIMER1_COMPB", "TIMER1_OVF", "TIMER0_COMPA",
    "TIMER0_COMPB", "TIMER0_OVF", "SPI_STC", "USART_RX", "USART_UDRE", "USART_TX", "ADC",
    "EE_READY", "ANALOG_COMP", "TWI", "SPM_READY"};

typedef struct {
    double angle_rad;
    double speed_radps;
    int64_t emitted_ticks;     /* quadrature steps already put on the pins */
    double motor_sign;         /* -1: motor wired reversed */
    double encoder_sign;       /* -1: encoder wired reversed */
    motor_model_t motor;       /* the real motor (config.h's, torque constant scaled) */
    avr_irq_t *pin_a;
    avr_irq_t *pin_b;
} wheel_t;

typedef struct {
    avr_t *avr;
    int master_fd;
    int slave_fd;
    FILE *status;
    int realtime;
    int freeze_wheels;
    struct timespec wall_start;
    avr_irq_t *uart_input;
    int uart_xon;
    uint8_t in_buf[IN_BUF_BYTES];
    size_t in_len, in_pos;
    uint8_t out_buf[OUT_BUF_BYTES];
    size_t out_len;
    uint64_t rx_bytes, tx_bytes, tx_dropped;
    /* interrupts */
    int running_vector;
    avr_cycle_count_t isr_entry;
    uint64_t isr_count[N_VECTORS];
    uint64_t isr_max[N_VECTORS];
    uint64_t isr_total;
    /* main loop */
    int loop_busy;
    avr_cycle_count_t loop_start;
    uint64_t loop_start_isr_total;
    uint64_t loop_count;
    uint64_t loop_max;
    uint64_t loop_max_own;
    uint64_t loop_busy_total;          /* all busy stretches added (cpu load of the main loop) */
    /* board -> host line, decoded */
    proto_decoder_t tx_dec;
    uint64_t tx_frames;
    uint64_t telemetry_count;
    avr_cycle_count_t first_telemetry_cycle, last_telemetry_cycle;
    proto_telemetry_t last_telemetry;
    proto_status_t last_status;
    uint64_t status_count;
    uint64_t hello_ack_count;
    /* host -> board line: fault injection */
    const char *control_path;
    int mode;                      /* 0 pass, 1 cut, 2 corrupt */
    int rx_block_pos;              /* bytes since the last 0x00 on the host -> board line */
    uint64_t rx_cut_bytes;
    proto_decoder_t rx_dec;            /* what the board receives, decoded */
    uint64_t rx_torque_cmds;           /* valid TORQUE_CMD frames fed to the board */
    uint64_t rx_corrupted_frames;
    avr_cycle_count_t last_rx_cycle;
    uint64_t frame_end_index;          /* rx_bytes count at the last frame-ending 0x00 fed */
    avr_cycle_count_t frame_end_read_cycle;   /* when the firmware's RX ISR took that byte */
    /* wheels */
    motor_model_t motor;
    double inertia_kgm2;
    double viscous_nms;
    wheel_t wheel[2];
    double duty[2];
    int32_t pwm_counts[2];
    avr_cycle_count_t pwm_change_cycle;   /* last change of either PWM output */
    unsigned step;
    uint64_t next_status_us;
} harness_t;

static volatile sig_atomic_t g_stop;

static void on_signal(int sig)
{
    (void)sig;
    g_stop = 1;
}

static double emu_seconds(const harness_t *h)
{
    return (double)h->avr->cycle / (double)h->avr->frequency;
}

static double wall_seconds(const harness_t *h)
{
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (double)(now.tv_sec - h->wall_start.tv_sec) +
           1e-9 * (double)(now.tv_nsec - h->wall_start.tv_nsec);
}

/* ---- UART <-> pty ------------------------------------------------------------------------ */
static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = param;
    h->tx_bytes++;
    proto_msg_t m;
    if (proto_decoder_feed(&h->tx_dec, (uint8_t)value, &m) == PROTO_FEED_FRAME) {
        h->tx_frames++;
        if (m.type == PROTO_TELEMETRY) {
            if (h->telemetry_count == 0) {
                h->first_telemetry_cycle = h->avr->cycle;
            }
            h->last_telemetry_cycle = h->avr->cycle;
            h->telemetry_count++;
            h->last_telemetry = m.u.telemetry;
        } else if (m.type == PROTO_STATUS) {
            h->status_count++;
            h->last_status = m.u.status;
        } else if (m.type == PROTO_HELLO_ACK) {
            h->hello_ack_count++;
        }
    }
    if (h->out_len < OUT_BUF_BYTES) {
        h->out_buf[h->out_len++] = (uint8_t)value;
    } else {
        h->tx_dropped++;
    }
}

static void uart_xon_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    ((harness_t *)param)->uart_xon = 1;
}

static void uart_xoff_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)value;
    ((harness_t *)param)->uart_xon = 0;
}

static void pty_poll(harness_t *h)
{
    if (h->out_len > 0) {
        const ssize_t n = write(h->master_fd, h->out_buf, h->out_len);
        if (n > 0) {
            memmove(h->out_buf, h->out_buf + n, h->out_len - (size_t)n);
            h->out_len -= (size_t)n;
        } else if (n < 0 && errno != EAGAIN && errno != EINTR) {
            h->tx_dropped += h->out_len;   /* nobody can read: drop, as a real line would */
            h->out_len = 0;
        }
        if (h->out_len > OUT_BUF_BYTES / 2) {   /* no reader: keep only recent bytes */
            h->tx_dropped += h->out_len;
            h->out_len = 0;
        }
    }
    if (h->in_pos == h->in_len) {
        h->in_pos = h->in_len = 0;
        const ssize_t n = read(h->master_fd, h->in_buf, IN_BUF_BYTES);
        if (n > 0) {
            h->in_len = (size_t)n;
        }
    }
    while (h->uart_xon && h->in_pos < h->in_len) {
        uint8_t byte = h->in_buf[h->in_pos++];
        const int pos = h->rx_block_pos;
        h->rx_block_pos = byte == 0x00 ? 0 : pos + 1;
        if (h->mode == 1) {
            h->rx_cut_bytes++;
            continue;
        }
        if (h->mode == 2 && byte != 0x00 && pos == 1) {
            /* the first data byte after the COBS code byte is the header byte: a flipped bit
             * is a single-bit error the CRC always detects; never turn it into a delimiter */
            byte = (uint8_t)((byte ^ 0x04) ? (byte ^ 0x04) : (byte ^ 0x08));
            h->rx_corrupted_frames++;
        }
        h->rx_bytes++;
        h->last_rx_cycle = h->avr->cycle;
        proto_msg_t m;
        if (proto_decoder_feed(&h->rx_dec, byte, &m) == PROTO_FEED_FRAME && m.type == PROTO_TORQUE_CMD) {
            h->rx_torque_cmds++;
        }
        if (byte == 0x00 && pos > 0) {
            h->frame_end_index = h->rx_bytes;
        }
        avr_raise_irq(h->uart_input, byte);
    }
}

static void read_control(harness_t *h)
{
    if (!h->control_path) {
        return;
    }
    FILE *f = fopen(h->control_path, "r");
    if (!f) {
        return;
    }
    char word[16] = {0};
    if (fscanf(f, "%15s", word) == 1) {
        if (!strcmp(word, "pass")) {
            h->mode = 0;
        } else if (!strcmp(word, "cut")) {
            h->mode = 1;
        } else if (!strcmp(word, "corrupt")) {
            h->mode = 2;
        }
    }
    fclose(f);
}

/* ---- interrupt and main-loop timing ------------------------------------------------------- */
static void isr_running_hook(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    harness_t *h = param;
    const avr_cycle_count_t now = h->avr->cycle;
    if (h->running_vector > 0 && h->running_vector < N_VECTORS) {
        const uint64_t d = now - h->isr_entry;
        h->isr_total += d;
        if (d > h->isr_max[h->running_vector]) {
            h->isr_max[h->running_vector] = d;
        }
    }
    h->running_vector = (int)value;
    h->isr_entry = now;
    if (value > 0 && value < N_VECTORS) {
        h->isr_count[value]++;
        /* the n-th USART_RX interrupt reads the n-th byte fed (the firmware counts overruns) */
        if (value == VECTOR_USART_RX && h->isr_count[value] == h->frame_end_index) {
            h->frame_end_read_cycle = now;
        }
    }
}

static void gpior0_write(struct avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    harness_t *h = param;
    avr->data[addr] = v;
    if (v && !h->loop_busy) {
        h->loop_busy = 1;
        h->loop_start = avr->cycle;
        h->loop_start_isr_total = h->isr_total;
    } else if (!v && h->loop_busy) {
        h->loop_busy = 0;
        const uint64_t d = avr->cycle - h->loop_start;
        const uint64_t own = d - (h->isr_total - h->loop_start_isr_total);
        h->loop_count++;
        h->loop_busy_total += d;
        if (d > h->loop_max) {
            h->loop_max = d;
        }
        if (own > h->loop_max_own) {
            h->loop_max_own = own;
        }
    }
}

/* ---- PWM read-out and wheel model ---------------------------------------------------------- */
static uint16_t reg16(const avr_t *avr, unsigned low)
{
    return (uint16_t)(avr->data[low] | (avr->data[low + 1] << 8));
}

static void read_pwm(harness_t *h)
{
    const avr_t *avr = h->avr;
    const int32_t before[2] = {h->pwm_counts[0], h->pwm_counts[1]};
    const uint16_t top = reg16(avr, REG_ICR1L);
    const uint8_t tccr1a = avr->data[REG_TCCR1A];
    const uint8_t ddrb = avr->data[REG_DDRB];
    const int dir[2] = {(avr->data[REG_PORTB] >> PIN_DIR_LEFT) & 1,
                        (avr->data[REG_PORTB] >> PIN_DIR_RIGHT) & 1};
    const int driven[2] = {((tccr1a >> COM1A1_BIT) & 1) && ((ddrb >> PIN_PWM_LEFT) & 1),
                           ((tccr1a >> COM1B1_BIT) & 1) && ((ddrb >> PIN_PWM_RIGHT) & 1)};
    const uint16_t ocr[2] = {reg16(avr, REG_OCR1AL), reg16(avr, REG_OCR1BL)};
    for (int i = 0; i < 2; i++) {
        if (!driven[i] || top == 0) {
            h->duty[i] = 0.0;
            h->pwm_counts[i] = 0;
            continue;
        }
        const uint16_t c = ocr[i] > top ? top : ocr[i];
        h->pwm_counts[i] = dir[i] ? -(int32_t)c : (int32_t)c;
        h->duty[i] = (double)h->pwm_counts[i] / (double)top;
    }
    if (before[0] != h->pwm_counts[0] || before[1] != h->pwm_counts[1]) {
        h->pwm_change_cycle = avr->cycle;
    }
}

static void emit_encoder_step(harness_t *h, wheel_t *w)
{
    const double ticks =
        w->encoder_sign * w->angle_rad / (2.0 * M_PI) * (double)ENCODER_TICKS_PER_REV;
    const int64_t target = (int64_t)floor(ticks);
    if (target == w->emitted_ticks) {
        return;
    }
    w->emitted_ticks += target > w->emitted_ticks ? 1 : -1;
    /* forward Gray sequence AB: 11 -> 10 -> 00 -> 01 (matches QUAD_TABLE in src/hal.c); count 0
     * is AB = 11, the idle level of pulled-up lines, so the firmware's pull-ups agree at start */
    static const uint8_t GRAY[4] = {0x3, 0x2, 0x0, 0x1};
    const uint8_t ab = GRAY[((w->emitted_ticks % 4) + 4) % 4];
    avr_raise_irq(w->pin_a, (ab >> 1) & 1);
    avr_raise_irq(w->pin_b, ab & 1);
    (void)h;
}

static void step_wheels(harness_t *h)
{
    const double dt = MODEL_STEP_US * 1e-6;
    read_pwm(h);
    for (int i = 0; i < 2; i++) {
        wheel_t *w = &h->wheel[i];
        if (!h->freeze_wheels) {
            /* a reversed motor: its shaft turns -G omega, its torque acts on the wheel reversed */
            const double tau = w->motor_sign * motor_torque_from_duty(&w->motor, (float)h->duty[i],
                                                                      (float)(w->motor_sign * w->speed_radps));
            w->speed_radps += dt * (tau - h->viscous_nms * w->speed_radps) / h->inertia_kgm2;
            w->angle_rad += dt * w->speed_radps;
        }
        emit_encoder_step(h, w);
    }
}

/* ---- status --------------------------------------------------------------------------- */
static void emit_status(harness_t *h, int final)
{
    if (!h->status) {
        return;
    }
    FILE *f = h->status;
    fprintf(f,
            "{\"t_s\":%.6f,\"cycle\":%llu,\"wall_s\":%.6f,\"duty\":[%.5f,%.5f],"
            "\"pwm_counts\":[%d,%d],\"pwm_change_t_s\":%.6f,\"pwm_top\":%u,\"wheel_rad\":[%.6f,%.6f],"
            "\"wheel_radps\":[%.5f,%.5f],\"encoder_ticks\":[%lld,%lld],"
            "\"rx_bytes\":%llu,\"tx_bytes\":%llu,\"tx_dropped\":%llu,\"tx_frames\":%llu,"
            "\"mode\":\"%s\",\"rx_cut_bytes\":%llu,\"rx_corrupted_frames\":%llu,\"last_rx_t_s\":%.6f,\"last_frame_rx_t_s\":%.6f,"
            "\"rx_torque_cmds\":%llu,\"telemetry_count\":%llu,\"first_telemetry_t_s\":%.6f,\"last_telemetry_t_s\":%.6f,"
            "\"telemetry\":{\"ticks\":[%d,%d],\"vel_mradps\":[%d,%d],\"cmd_seq\":%u,\"flags\":%u},"
            "\"status_count\":%llu,\"hello_ack_count\":%llu,"
            "\"board\":{\"uptime_ms\":%lu,\"applied_e4nm\":[%d,%d],\"crc_errors\":%u,"
            "\"frame_errors\":%u,\"type_errors\":%u,\"rx_gaps\":%u,\"watchdog_trips\":%u,"
            "\"flags\":%u,\"cmd_seq\":%u},"
            "\"wdtcsr\":%u,\"loop_count\":%llu,\"loop_busy_cycles\":%llu,\"isr_cycles\":%llu,\"loop_max_cycles\":%llu,\"loop_max_own_cycles\":%llu,"
            "\"isr_max_cycles\":{",
            emu_seconds(h), (unsigned long long)h->avr->cycle, wall_seconds(h), h->duty[0],
            h->duty[1], h->pwm_counts[0], h->pwm_counts[1],
            (double)h->pwm_change_cycle / (double)h->avr->frequency, (unsigned)reg16(h->avr, REG_ICR1L),
            h->wheel[0].angle_rad, h->wheel[1].angle_rad, h->wheel[0].speed_radps,
            h->wheel[1].speed_radps, (long long)h->wheel[0].emitted_ticks,
            (long long)h->wheel[1].emitted_ticks, (unsigned long long)h->rx_bytes,
            (unsigned long long)h->tx_bytes, (unsigned long long)h->tx_dropped,
            (unsigned long long)h->tx_frames,
            h->mode == 0 ? "pass" : (h->mode == 1 ? "cut" : "corrupt"),
            (unsigned long long)h->rx_cut_bytes, (unsigned long long)h->rx_corrupted_frames,
            (double)h->last_rx_cycle / (double)h->avr->frequency,
            (double)h->frame_end_read_cycle / (double)h->avr->frequency,
            (unsigned long long)h->rx_torque_cmds, (unsigned long long)h->telemetry_count,
            (double)h->first_telemetry_cycle / (double)h->avr->frequency,
            (double)h->last_telemetry_cycle / (double)h->avr->frequency,
            h->last_telemetry.left_ticks, h->last_telemetry.right_ticks,
            h->last_telemetry.left_vel_mradps, h->last_telemetry.right_vel_mradps,
            h->last_telemetry.cmd_seq, h->last_telemetry.flags,
            (unsigned long long)h->status_count, (unsigned long long)h->hello_ack_count,
            (unsigned long)h->last_status.uptime_ms, h->last_status.left_applied_e4nm,
            h->last_status.right_applied_e4nm, h->last_status.crc_errors,
            h->last_status.frame_errors, h->last_status.type_errors, h->last_status.rx_gaps,
            h->last_status.watchdog_trips, h->last_status.flags, h->last_status.cmd_seq,
            (unsigned)h->avr->data[REG_WDTCSR], (unsigned long long)h->loop_count,
            (unsigned long long)h->loop_busy_total,
            (unsigned long long)h->isr_total, (unsigned long long)h->loop_max,
            (unsigned long long)h->loop_max_own);
    int first = 1;
    for (int v = 1; v < N_VECTORS; v++) {
        if (h->isr_count[v]) {
            fprintf(f, "%s\"%s\":%llu", first ? "" : ",", VECTOR_NAMES[v],
                    (unsigned long long)h->isr_max[v]);
            first = 0;
        }
    }
    fprintf(f, "},\"isr_count\":{");
    first = 1;
    for (int v = 1; v < N_VECTORS; v++) {
        if (h->isr_count[v]) {
            fprintf(f, "%s\"%s\":%llu", first ? "" : ",", VECTOR_NAMES[v],
                    (unsigned long long)h->isr_count[v]);
            first = 0;
        }
    }
    fprintf(f, "},\"state\":%d,\"final\":%s}\n", h->avr->state, final ? "true" : "false");
    fflush(f);
}

/* ---- the periodic cycle timer: wheels, pty, pacing, status ------------------------------- */
static uint32_t *g_profile;   /* PC histogram (word addresses), FW_SIM_PROFILE=FILE */

static avr_cycle_count_t profile_tick(struct avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)param;
    if (avr->state == cpu_Running && avr->pc / 2 < 16384) {
        g_profile[avr->pc / 2]++;
    }
    return when + 97;   /* prime period: no aliasing with the firmware's loops */
}

static avr_cycle_count_t periodic(struct avr_t *avr, avr_cycle_count_t when, void *param)
{
    harness_t *h = param;
    step_wheels(h);
    h->step++;
    if (h->step % IO_POLL_STEPS == 0) {
        pty_poll(h);
        if (h->realtime) {
            const double ahead_s = emu_seconds(h) - wall_seconds(h);
            if (ahead_s > 200e-6) {
                const struct timespec ts = {0, (long)(ahead_s * 1e9)};
                nanosleep(&ts, NULL);
            }
        }
    }
    const uint64_t now_us = (uint64_t)(emu_seconds(h) * 1e6);
    if (now_us >= h->next_status_us) {
        h->next_status_us += STATUS_PERIOD_US;
        read_control(h);
        emit_status(h, 0);
    }
    return when + avr_usec_to_cycles(avr, MODEL_STEP_US);
}

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
    (void)avr;
    (void)how_long;   /* pacing is done against the wall clock in periodic() */
}

static void usage(void)
{
    fprintf(stderr, "usage: formation_fw_sim FIRMWARE.elf [--status FILE] [--link PATH] "
                    "[--duration-s S] [--no-realtime] [--freeze-wheels] [--control FILE]\n"
                    "       [--reverse-motor left|right] [--reverse-encoder left|right] "
                    "[--kt-scale L,R]\n");
}

int main(int argc, char **argv)
{
    const char *elf = NULL, *status_path = NULL, *link_path = NULL;
    double duration_s = 0.0;
    double kt_scale[2] = {1.0, 1.0};
    static harness_t h;
    h.realtime = 1;
    for (int i = 0; i < 2; i++) {
        h.wheel[i].motor_sign = 1.0;
        h.wheel[i].encoder_sign = 1.0;
    }
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--status") && i + 1 < argc) {
            status_path = argv[++i];
        } else if (!strcmp(argv[i], "--link") && i + 1 < argc) {
            link_path = argv[++i];
        } else if (!strcmp(argv[i], "--duration-s") && i + 1 < argc) {
            char *end = NULL;
            duration_s = strtod(argv[++i], &end);
            if (!end || *end || !(duration_s > 0.0)) {
                fprintf(stderr, "formation_fw_sim: --duration-s: expected a positive number\n");
                return 2;
            }
        } else if (!strcmp(argv[i], "--control") && i + 1 < argc) {
            h.control_path = argv[++i];
        } else if (!strcmp(argv[i], "--no-realtime")) {
            h.realtime = 0;
        } else if (!strcmp(argv[i], "--freeze-wheels")) {
            h.freeze_wheels = 1;
        } else if ((!strcmp(argv[i], "--reverse-motor") || !strcmp(argv[i], "--reverse-encoder")) &&
                   i + 1 < argc) {
            const int motor = !strcmp(argv[i], "--reverse-motor");
            const char *w = argv[++i];
            const int idx = !strcmp(w, "left") ? 0 : !strcmp(w, "right") ? 1 : -1;
            if (idx < 0) {
                fprintf(stderr, "formation_fw_sim: %s: expected left or right\n", argv[i - 1]);
                return 2;
            }
            if (motor) {
                h.wheel[idx].motor_sign = -1.0;
            } else {
                h.wheel[idx].encoder_sign = -1.0;
            }
        } else if (!strcmp(argv[i], "--kt-scale") && i + 1 < argc) {
            char *end = NULL;
            kt_scale[0] = strtod(argv[++i], &end);
            kt_scale[1] = (end && *end == ',') ? strtod(end + 1, &end) : kt_scale[0];
            if (!end || *end || !(kt_scale[0] >= 0.1 && kt_scale[0] <= 10.0) ||
                !(kt_scale[1] >= 0.1 && kt_scale[1] <= 10.0)) {
                fprintf(stderr, "formation_fw_sim: --kt-scale: expected L,R in [0.1, 10]\n");
                return 2;
            }
        } else if (argv[i][0] != '-' && !elf) {
            elf = argv[i];
        } else {
            usage();
            return 2;
        }
    }
    if (!elf) {
        usage();
        return 2;
    }
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf, &fw) != 0) {
        fprintf(stderr, "formation_fw_sim: %s: cannot read ELF firmware\n", elf);
        return 2;
    }
    if (!fw.mmcu[0]) {
        strcpy(fw.mmcu, "atmega328p");
    }
    if (!fw.frequency) {
        fw.frequency = F_CPU;
    }
    avr_t *avr = avr_make_mcu_by_name(fw.mmcu);
    if (!avr) {
        fprintf(stderr, "formation_fw_sim: %s: unknown MCU %s\n", elf, fw.mmcu);
        return 2;
    }
    avr_init(avr);
    avr_load_firmware(avr, &fw);
    avr->sleep = no_sleep;
    avr->log = 0;
    h.avr = avr;
    proto_decoder_init(&h.tx_dec, PROTO_VERSION);
    proto_decoder_init(&h.rx_dec, PROTO_VERSION);

    if (status_path) {
        h.status = fopen(status_path, "w");
        if (!h.status) {
            fprintf(stderr, "formation_fw_sim: --status %s: %s\n", status_path, strerror(errno));
            return 2;
        }
    }
    char slave_name[128];
    if (openpty(&h.master_fd, &h.slave_fd, slave_name, NULL, NULL) < 0) {
        fprintf(stderr, "formation_fw_sim: openpty: %s\n", strerror(errno));
        return 1;
    }
    struct termios tio;
    tcgetattr(h.slave_fd, &tio);
    cfmakeraw(&tio);
    tcsetattr(h.slave_fd, TCSANOW, &tio);
    fcntl(h.master_fd, F_SETFL, fcntl(h.master_fd, F_GETFL) | O_NONBLOCK);
    if (link_path) {
        unlink(link_path);
        if (symlink(slave_name, link_path) != 0) {
            fprintf(stderr, "formation_fw_sim: --link %s: %s\n", link_path, strerror(errno));
            return 2;
        }
    }

    /* UART 0 */
    h.uart_xon = 1;
    h.uart_input = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                            uart_out_hook, &h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON),
                            uart_xon_hook, &h);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF),
                            uart_xoff_hook, &h);
    /* interrupts and loop marker */
    avr_irq_register_notify(avr_get_interrupt_irq(avr, AVR_INT_ANY) + AVR_INT_IRQ_RUNNING,
                            isr_running_hook, &h);
    avr_register_io_write(avr, REG_GPIOR0, gpior0_write, &h);
    /* encoders */
    h.wheel[0].pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_ENC_LEFT_A);
    h.wheel[0].pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_ENC_LEFT_B);
    h.wheel[1].pin_a = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_ENC_RIGHT_A);
    h.wheel[1].pin_b = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_ENC_RIGHT_B);
    for (int i = 0; i < 2; i++) {
        avr_raise_irq(h.wheel[i].pin_a, 1);
        avr_raise_irq(h.wheel[i].pin_b, 1);
    }
    /* plant: the firmware's motor constants; wheel + reflected half robot (2.5 kg, r = 35 mm) */
    h.motor = (motor_model_t){MOTOR_SUPPLY_V, MOTOR_TORQUE_CONSTANT_NM_PER_A, MOTOR_RESISTANCE_OHM,
                              MOTOR_GEAR_RATIO, MOTOR_GEAR_EFFICIENCY};
    for (int i = 0; i < 2; i++) {
        h.wheel[i].motor = h.motor;
        h.wheel[i].motor.torque_constant = (float)(MOTOR_TORQUE_CONSTANT_NM_PER_A * kt_scale[i]);
    }
    h.inertia_kgm2 = 1.6e-3;
    h.viscous_nms = 2e-3;

    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGPIPE, SIG_IGN);
    printf("PTY %s\n", slave_name);
    fflush(stdout);

    clock_gettime(CLOCK_MONOTONIC, &h.wall_start);
    avr_cycle_timer_register_usec(avr, MODEL_STEP_US, periodic, &h);
    const char *profile_path = getenv("FW_SIM_PROFILE");
    if (profile_path) {
        g_profile = calloc(16384, sizeof *g_profile);
        avr_cycle_timer_register(avr, 97, profile_tick, NULL);
    }
    const avr_cycle_count_t end_cycle =
        duration_s > 0.0 ? (avr_cycle_count_t)(duration_s * (double)avr->frequency) : 0;
    int state = cpu_Running;
    while (!g_stop && state != cpu_Done && state != cpu_Crashed) {
        state = avr_run(avr);
        if (end_cycle && avr->cycle >= end_cycle) {
            break;
        }
    }
    emit_status(&h, 1);
    if (g_profile) {
        FILE *pf = fopen(profile_path, "w");
        for (unsigned i = 0; pf && i < 16384; i++) {
            if (g_profile[i]) {
                fprintf(pf, "%u %u\n", i * 2, g_profile[i]);
            }
        }
        if (pf) {
            fclose(pf);
        }
    }
    if (state == cpu_Crashed) {
        fprintf(stderr, "formation_fw_sim: firmware crashed at pc=0x%04x\n", avr->pc);
    }
    if (link_path) {
        unlink(link_path);
    }
    if (h.status) {
        fclose(h.status);
    }
    close(h.master_fd);
    close(h.slave_fd);
    avr_terminate(avr);
    return state == cpu_Crashed ? 1 : 0;
}
