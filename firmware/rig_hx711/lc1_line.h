/*
 * The pure parts of the rig-lc1 HX711 firmware: line formatting, the checksum, the HX711's 24-bit
 * sign extension, the capture clock arithmetic and the rate estimate. No I/O and no AVR registers,
 * so the same file compiles for the ATmega328P and for the host (tests/test_firmware_host.py calls
 * it through ctypes and compares every line with the rig's own codec).
 *
 * The format is specified in protocols/loadcell-formats.md (section 1, rig-lc1).
 */
#ifndef RIG_LC1_LINE_H
#define RIG_LC1_LINE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Longest data line: "$LC,65535,4294967295,-2147483648*hh\r\n" is 37 bytes (no terminating NUL). */
#define LC1_MAX_LINE_BYTES 37
/* Longest information line, "#" and CR LF included: the host's line limit (protocols/loadcell-formats.md). */
#define LC1_MAX_INFO_BYTES 74

/* XOR of the `n` bytes at `body` (the bytes between "$" and "*"). */
uint8_t lc1_checksum(const char *body, uint8_t n);

/* Write the data line for one sample at `out` (room for LC1_MAX_LINE_BYTES); return its length. */
uint8_t lc1_format_sample(char *out, uint16_t seq, uint32_t t_us, int32_t raw);

/*
 * Write "#" + `text` + CR LF at `out` (room for LC1_MAX_INFO_BYTES); return its length. Characters
 * an information line may not carry ("$", "#", control and non-ASCII bytes) become "?", and text
 * beyond the limit is cut, so whatever the caller passes, the host receives a valid information line.
 */
uint8_t lc1_format_info(char *out, const char *text);

/* The HX711's 24-bit two's-complement code (bits 23..0 of `code`) as a signed 32-bit count. */
int32_t hx711_sign_extend(uint32_t code);

/*
 * Microseconds of a Timer1 capture, Timer1 counting 0.5 us ticks (16 MHz / 8) and wrapping every
 * 65536 ticks: `overflows` is the overflow count the firmware has serviced, `icr` the captured
 * count and `overflow_pending` whether TOV1 was set but not yet serviced when the capture was read
 * (a capture with a small `icr` then belongs after that overflow). Wraps at 2^32 us, as t-us must.
 */
uint32_t capture_time_us(uint32_t overflows, uint16_t icr, uint8_t overflow_pending);

/* Samples per second for a conversion period in microseconds, rounded; 0 for a period of 0. */
uint16_t rate_sps(uint32_t period_us);

#ifdef __cplusplus
}
#endif

#endif
