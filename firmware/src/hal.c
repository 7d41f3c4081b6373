/* hal.c - ATmega328P peripherals; see hal.h. */
#include "hal.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <util/atomic.h>

#include "config.h"

/* ---- reset cause: captured and the watchdog disabled before main() runs ----------------- */
static uint8_t g_mcusr __attribute__((section(".noinit")));

void hal_capture_reset_cause(void) __attribute__((naked, used, section(".init3")));
void hal_capture_reset_cause(void)
{
    g_mcusr = MCUSR;
    MCUSR = 0;
    wdt_disable();
}

uint8_t hal_reset_cause(void)
{
    return g_mcusr;
}

/* ---- UART ------------------------------------------------------------------------------ */
static volatile uint8_t rx_buf[UART_RX_BUFFER_BYTES];
static volatile uint8_t rx_head;   /* written by ISR */
static volatile uint8_t rx_tail;   /* written by main */
static volatile uint8_t rx_overruns;
static volatile uint8_t tx_buf[UART_TX_BUFFER_BYTES];
static volatile uint8_t tx_head;   /* written by main */
static volatile uint8_t tx_tail;   /* written by ISR */

#define RX_MASK ((uint8_t)(UART_RX_BUFFER_BYTES - 1u))
#define TX_MASK ((uint8_t)(UART_TX_BUFFER_BYTES - 1u))
_Static_assert(UART_TX_BUFFER_BYTES <= 256u && (UART_TX_BUFFER_BYTES & (UART_TX_BUFFER_BYTES - 1u)) == 0,
               "UART_TX_BUFFER_BYTES: power of two <= 256 (uint8_t indices)");
_Static_assert(UART_RX_BUFFER_BYTES <= 256u && (UART_RX_BUFFER_BYTES & (UART_RX_BUFFER_BYTES - 1u)) == 0,
               "UART_RX_BUFFER_BYTES: power of two <= 256 (uint8_t indices)");

ISR(USART_RX_vect)
{
    const uint8_t status = UCSR0A;
    const uint8_t byte = UDR0;
    const uint8_t next = (uint8_t)((rx_head + 1u) & RX_MASK);
    if ((status & ((1 << FE0) | (1 << DOR0))) != 0 || next == rx_tail) {
        if (rx_overruns != 0xFF) {
            rx_overruns++;
        }
        if (next == rx_tail) {
            return;
        }
    }
    rx_buf[rx_head] = byte;
    rx_head = next;
}

ISR(USART_UDRE_vect)
{
    if (tx_tail == tx_head) {
        UCSR0B &= (uint8_t)~(1 << UDRIE0);
        return;
    }
    UDR0 = tx_buf[tx_tail];
    tx_tail = (uint8_t)((tx_tail + 1u) & TX_MASK);
}

bool hal_uart_read(uint8_t *byte)
{
    const uint8_t tail = rx_tail;
    if (tail == rx_head) {
        return false;
    }
    *byte = rx_buf[tail];
    rx_tail = (uint8_t)((tail + 1u) & RX_MASK);
    return true;
}

uint8_t hal_uart_rx_overruns(void)
{
    return rx_overruns;
}

uint16_t hal_uart_tx_queued(void)
{
    return (uint8_t)(tx_head - tx_tail) & TX_MASK;
}

uint16_t hal_uart_tx_free(void)
{
    return (uint16_t)((uint8_t)(tx_tail - tx_head - 1u) & TX_MASK);
}

bool hal_uart_write(const uint8_t *data, uint16_t len)
{
    if (len > hal_uart_tx_free()) {
        return false;
    }
    uint8_t head = tx_head;
    for (uint16_t i = 0; i < len; i++) {
        tx_buf[head] = data[i];
        head = (uint8_t)((head + 1u) & TX_MASK);
    }
    tx_head = head;
    UCSR0B |= (1 << UDRIE0);
    return true;
}

static void uart_init(void)
{
    const uint16_t ubrr = (uint16_t)((F_CPU + 4UL * UART_BAUD) / (8UL * UART_BAUD) - 1UL);
    UBRR0H = (uint8_t)(ubrr >> 8);
    UBRR0L = (uint8_t)ubrr;
    UCSR0A = (1 << U2X0);
    UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);                  /* 8N1 */
    UCSR0B = (1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0);
}

/* ---- PWM ------------------------------------------------------------------------------- */
static void pwm_init(void)
{
    PORTB &= (uint8_t)~((1 << PIN_PWM_LEFT) | (1 << PIN_PWM_RIGHT) | (1 << PIN_DIR_LEFT) |
                        (1 << PIN_DIR_RIGHT));
    DDRB |= (1 << PIN_PWM_LEFT) | (1 << PIN_PWM_RIGHT) | (1 << PIN_DIR_LEFT) | (1 << PIN_DIR_RIGHT) |
            (1 << PIN_LED);
    ICR1 = PWM_TOP;
    OCR1A = 0;
    OCR1B = 0;
    /* mode 10: phase-correct PWM, TOP = ICR1; non-inverting on OC1A/OC1B; prescaler 1 */
    TCCR1A = (1 << COM1A1) | (1 << COM1B1) | (1 << WGM11);
    TCCR1B = (1 << WGM13) | (1 << CS10);
}

static uint16_t magnitude(int16_t counts)
{
    int32_t c = counts;
    if (c < 0) {
        c = -c;
    }
    if (c > (int32_t)PWM_TOP) {
        c = PWM_TOP;
    }
    return (uint16_t)c;
}

void hal_pwm_set(int16_t left_counts, int16_t right_counts)
{
    uint8_t dir = PORTB & (uint8_t)~((1 << PIN_DIR_LEFT) | (1 << PIN_DIR_RIGHT));
    if (left_counts < 0) {
        dir |= (1 << PIN_DIR_LEFT);
    }
    if (right_counts < 0) {
        dir |= (1 << PIN_DIR_RIGHT);
    }
    const uint16_t l = magnitude(left_counts);
    const uint16_t r = magnitude(right_counts);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        PORTB = dir;
        OCR1A = l;   /* double-buffered by hardware: takes effect at TOP */
        OCR1B = r;
    }
}

/* ---- encoders ---------------------------------------------------------------------------- */
/* x4 quadrature: index = (previous AB << 2) | current AB; +1 / -1 / 0 (0 also for invalid jumps) */
static const int8_t QUAD_TABLE[16] = {0, 1, -1, 0, -1, 0, 0, 1, 1, 0, 0, -1, 0, -1, 1, 0};
static volatile int32_t enc_left;
static volatile int32_t enc_right;
static uint8_t enc_prev_left;
static uint8_t enc_prev_right;

static inline uint8_t ab(uint8_t pins, uint8_t a_bit, uint8_t b_bit)
{
    return (uint8_t)((((pins >> a_bit) & 1u) << 1) | ((pins >> b_bit) & 1u));
}

ISR(PCINT2_vect)
{
    const uint8_t pins = PIND;
    const uint8_t l = ab(pins, PIN_ENC_LEFT_A, PIN_ENC_LEFT_B);
    const uint8_t r = ab(pins, PIN_ENC_RIGHT_A, PIN_ENC_RIGHT_B);
    enc_left += QUAD_TABLE[(uint8_t)(enc_prev_left << 2) | l];
    enc_right += QUAD_TABLE[(uint8_t)(enc_prev_right << 2) | r];
    enc_prev_left = l;
    enc_prev_right = r;
}

static void encoders_init(void)
{
    const uint8_t mask = (1 << PIN_ENC_LEFT_A) | (1 << PIN_ENC_LEFT_B) | (1 << PIN_ENC_RIGHT_A) |
                         (1 << PIN_ENC_RIGHT_B);
    DDRD &= (uint8_t)~mask;
    PORTD |= mask;     /* pull-ups for open-collector encoders; PORTD is not written again */
    const uint8_t pins = PIND;
    enc_prev_left = ab(pins, PIN_ENC_LEFT_A, PIN_ENC_LEFT_B);
    enc_prev_right = ab(pins, PIN_ENC_RIGHT_A, PIN_ENC_RIGHT_B);
    PCMSK2 = mask;
    PCICR |= (1 << PCIE2);
}

void hal_encoders_read(int32_t *left_ticks, int32_t *right_ticks)
{
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        *left_ticks = enc_left;
        *right_ticks = enc_right;
    }
}

/* ---- tick -------------------------------------------------------------------------------- */
static volatile uint32_t millis_count;
static volatile uint8_t control_countdown = CONTROL_PERIOD_MS;
static volatile uint8_t control_pending;      /* periods since the main loop took one */
static volatile int32_t control_left, control_right;

ISR(TIMER2_COMPA_vect)
{
    millis_count++;
    if (--control_countdown == 0) {
        control_countdown = CONTROL_PERIOD_MS;
        control_left = enc_left;      /* exact period boundary: the encoder ISR cannot nest */
        control_right = enc_right;
        if (control_pending != 0xFF) {
            control_pending++;
        }
    }
}

static void tick_init(void)
{
    TCCR2A = (1 << WGM21);                       /* CTC */
    OCR2A = (uint8_t)(F_CPU / 64UL / TICK_HZ - 1UL);   /* 249 -> exactly 1 kHz */
    TIMSK2 = (1 << OCIE2A);
    TCCR2B = (1 << CS22);                        /* prescaler 64 */
}

uint32_t hal_millis(void)
{
    uint32_t ms;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        ms = millis_count;
    }
    return ms;
}

bool hal_take_control_tick(int32_t *left_ticks, int32_t *right_ticks, uint8_t *periods)
{
    bool due = false;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE)
    {
        if (control_pending) {
            *periods = control_pending;
            *left_ticks = control_left;
            *right_ticks = control_right;
            control_pending = 0;
            due = true;
        }
    }
    return due;
}

/* ---- watchdog, idle, LED ----------------------------------------------------------------- */
void hal_watchdog_kick(void)
{
    wdt_reset();
}

void hal_idle(void)
{
    cli();
    if (rx_head == rx_tail && !control_pending) {
        GPIOR0 = 0;                              /* loop is idle (emulator measurement) */
        set_sleep_mode(SLEEP_MODE_IDLE);         /* timers and UART keep running */
        sleep_enable();
        sei();                                   /* the instruction after sei runs first: */
        sleep_cpu();                             /* no wake-up can be lost in between */
        sleep_disable();
    }
    sei();
}

void hal_loop_busy(void)
{
    GPIOR0 = 1;
}

void hal_led(bool on)
{
    if (on) {
        PORTB |= (1 << PIN_LED);
    } else {
        PORTB &= (uint8_t)~(1 << PIN_LED);
    }
}

void hal_init(void)
{
    uart_init();
    pwm_init();
    encoders_init();
    tick_init();
    wdt_enable(WDTO_60MS);
}
