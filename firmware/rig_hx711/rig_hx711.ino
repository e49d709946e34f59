/*
 * rig_hx711: streams every conversion of an HX711 (or HX717) load-cell ADC as a rig-lc1 line.
 *
 * Board: Arduino Uno or Nano (ATmega328P, 16 MHz). Wiring (docs/hardware-loadcell.md):
 *   HX711 DOUT   -> D8 (PB0, the ICP1 input-capture pin: Timer1 latches the data-ready edge)
 *   HX711 PD_SCK <- D9 (PB1)
 *   HX711 RATE   -> VCC for 80 samples/s, GND (most breakouts) for 10 samples/s
 *
 * What it sends (protocols/loadcell-formats.md, rig-lc1):
 *   - at boot, information lines: "#BOOT fw=... adc=... gain=A128 sps=... period-us=..." (the banner)
 *     and "#INFO ..." with the pins and baud rate;
 *   - then one line per conversion, "$LC,<seq>,<t-us>,<raw>*hh", the moment it has been read:
 *     seq counts every conversion read (also those it could not send), t-us is the time of the
 *     data-ready edge (DOUT falling) in microseconds since boot, and raw is the sign-extended 24-bit
 *     code, unfiltered and untared (0x7FFFFF and -0x800000 are the ADC's saturation codes);
 *   - "#WARN ..." when no conversion has come for a second (then it resets the ADC and tries again).
 *
 * How: the data-ready edge on D8 fires the Timer1 capture interrupt, which stamps the edge from the
 * hardware-latched counter (0.5 us ticks, jitter-free: no interrupt latency in the stamp), clocks
 * the 25 pulses out with interrupts off (25 pulses select channel A, gain 128 for the next
 * conversion; on the HX717 too) and queues the sample. loop() formats the queued samples and hands
 * each to the serial buffer once the whole line fits, so the reads never wait for the UART. If the
 * queue is full (the UART too slow for the rate), the conversion is read and dropped, and seq
 * still counts it, so the host sees the loss. In between, the CPU sleeps.
 */
#include <Arduino.h>
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <util/delay.h>

#include "lc1_line.h"

#ifndef RIG_BAUD
#define RIG_BAUD 115200
#endif
#ifndef RIG_ADC
#define RIG_ADC "HX711" /* the banner's name for the ADC; HX717: same pins, same 25-pulse read */
#endif
#define RIG_FIRMWARE "rig-hx711"
#define RIG_VERSION "1.0.0"

#define DOUT_BIT PB0 /* D8 */
#define SCK_BIT PB1  /* D9 */
#define NO_DATA_MS 1000UL /* longer than the 400 ms settling at 10 samples/s plus a period */

/* Samples read by the capture interrupt, waiting for loop() to send them. */
struct Sample {
    uint16_t seq;
    uint32_t t_us;
    int32_t raw;
};
#define QUEUE_LENGTH 8 /* a power of two */
static volatile struct Sample queue[QUEUE_LENGTH];
static volatile uint8_t queue_head; /* written by the interrupt */
static volatile uint8_t queue_tail; /* written by loop() */
static volatile uint16_t next_seq;
static volatile uint32_t timer1_overflows;
static volatile uint32_t last_conversion_ms;

ISR(TIMER1_OVF_vect)
{
    timer1_overflows++;
}

/* The 24 data bits, MSB first, then the 25th pulse (channel A, gain 128 next). Interrupts are off
 * (this runs in an interrupt handler), so no handler can stretch a high phase past the HX711's
 * 50 us limit or its 60 us power-down. Each phase lasts about 1 us, the datasheet's typical value. */
static uint32_t hx711_shift_in(void)
{
    uint32_t code = 0;
    for (uint8_t i = 0; i < 24; i++) {
        PORTB |= _BV(SCK_BIT);
        _delay_us(1);
        code = (code << 1) | ((PINB & _BV(DOUT_BIT)) ? 1U : 0U); /* DOUT is valid 0.1 us after the rise */
        PORTB &= (uint8_t)~_BV(SCK_BIT);
        _delay_us(1);
    }
    PORTB |= _BV(SCK_BIT);
    _delay_us(1);
    PORTB &= (uint8_t)~_BV(SCK_BIT);
    return code;
}

ISR(TIMER1_CAPT_vect)
{
    /* The data bits' own falling edges latch captures too; the interrupt they leave pending runs
     * right after the read, when DOUT is high again, and is ignored here. (Clearing ICF1 by a write
     * to TIFR1 would do on the chip, but simavr 1.6 then also clears a pending TOV1.) */
    if (PINB & _BV(DOUT_BIT))
        return;
    uint16_t icr = ICR1;
    uint8_t overflow_pending = (TIFR1 & _BV(TOV1)) ? 1 : 0;
    uint32_t t_us = capture_time_us(timer1_overflows, icr, overflow_pending);
    int32_t raw = hx711_sign_extend(hx711_shift_in());
    uint16_t seq = next_seq++;
    uint8_t head = queue_head;
    if ((uint8_t)(head - queue_tail) < QUEUE_LENGTH) {
        volatile struct Sample *slot = &queue[head & (QUEUE_LENGTH - 1)];
        slot->seq = seq;
        slot->t_us = t_us;
        slot->raw = raw;
        queue_head = head + 1;
    } /* else dropped: loop() fell behind by a whole queue; the seq gap tells the host */
    last_conversion_ms = millis();
}

/* Power the HX711 down (PD_SCK high > 60 us) and up again: it resets to channel A, gain 128. */
static void hx711_reset(void)
{
    PORTB |= _BV(SCK_BIT);
    _delay_us(100);
    PORTB &= (uint8_t)~_BV(SCK_BIT);
}

static void send_info(const char *text)
{
    char line[LC1_MAX_INFO_BYTES];
    uint8_t n = lc1_format_info(line, text);
    Serial.write((const uint8_t *)line, n);
}

static uint8_t queued(void)
{
    return (uint8_t)(queue_head - queue_tail);
}

void setup()
{
    Serial.begin(RIG_BAUD);
    DDRB |= _BV(SCK_BIT);
    PORTB &= (uint8_t)~_BV(SCK_BIT);
    DDRB &= (uint8_t)~_BV(DOUT_BIT);
    PORTB |= _BV(DOUT_BIT); /* pull-up: a missing HX711 reads "not ready" rather than noise */

    /* Timer1: normal mode, clock/8 (0.5 us ticks), capture on DOUT's falling edge, noise canceler on
     * (it delays every capture by the same 4 clocks). The Arduino core had set it up for PWM. */
    TCCR1A = 0;
    TCCR1B = _BV(ICNC1) | _BV(CS11);
    TCNT1 = 0;
    hx711_reset();
    TIFR1 = _BV(ICF1) | _BV(TOV1);
    TIMSK1 = _BV(ICIE1) | _BV(TOIE1);
    set_sleep_mode(SLEEP_MODE_IDLE);

    /* Time two conversions for the banner (the HX711 settles 400 ms at 10/s, 50 ms at 80/s), then
     * start seq at 0 with the next conversion. */
    uint32_t start_ms = millis();
    while (queued() < 2 && millis() - start_ms < 2 * NO_DATA_MS) {
    }
    uint32_t period_us = 0;
    noInterrupts();
    if (queued() >= 2) {
        uint8_t tail = queue_tail;
        period_us = queue[(tail + 1) & (QUEUE_LENGTH - 1)].t_us - queue[tail & (QUEUE_LENGTH - 1)].t_us;
    }
    queue_tail = queue_head;
    next_seq = 0;
    last_conversion_ms = millis();
    interrupts();

    char text[LC1_MAX_INFO_BYTES];
    snprintf(text, sizeof text, "BOOT fw=%s/%s adc=%s gain=A128 sps=%u period-us=%lu", RIG_FIRMWARE,
             RIG_VERSION, RIG_ADC, rate_sps(period_us), (unsigned long)period_us);
    send_info(text);
    snprintf(text, sizeof text, "INFO dout=D8 sck=D9 baud=%lu t-us=timer1-capture", (unsigned long)RIG_BAUD);
    send_info(text);
    if (period_us == 0)
        send_info("WARN no conversion from the ADC: check DOUT->D8, PD_SCK<-D9, VCC, GND");
}

void loop()
{
    /* A line goes to the serial buffer only whole and only if it fits, so Serial.write never waits;
     * a sample that does not fit yet waits in the queue (8 conversions: 100 ms at 80/s). */
    while (queued()) {
        volatile struct Sample *slot = &queue[queue_tail & (QUEUE_LENGTH - 1)];
        char line[LC1_MAX_LINE_BYTES];
        uint8_t n = lc1_format_sample(line, slot->seq, slot->t_us, slot->raw);
        if (Serial.availableForWrite() < n)
            break;
        Serial.write((const uint8_t *)line, n);
        queue_tail++;
    }
    noInterrupts();
    uint32_t since_ms = millis() - last_conversion_ms;
    interrupts();
    if (since_ms > NO_DATA_MS) {
        send_info("WARN no conversion for 1 s: resetting the ADC (check wiring and power)");
        hx711_reset();
        noInterrupts();
        last_conversion_ms = millis();
        interrupts();
    }
    /* Sleep until the next interrupt (capture, timer0's tick, the UART); the interrupts are enabled
     * by the instruction before `sleep`, so none can slip in between the check and the sleep. */
    noInterrupts();
    if (!queued()) {
        sleep_enable();
        interrupts();
        sleep_cpu();
        sleep_disable();
    }
    interrupts();
}
