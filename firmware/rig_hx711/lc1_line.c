/* The pure parts of the rig-lc1 HX711 firmware (see lc1_line.h). */
#include "lc1_line.h"

static const uint32_t POWERS_OF_TEN[10] = {
    1000000000UL, 100000000UL, 10000000UL, 1000000UL, 100000UL,
    10000UL,      1000UL,      100UL,      10UL,      1UL,
};

/* Decimal digits of `value` at `out`, no leading zeros; return how many. Repeated subtraction: on
 * the AVR a 32-bit division costs hundreds of cycles per digit, this at most 9 subtractions. */
static uint8_t put_decimal(char *out, uint32_t value)
{
    uint8_t n = 0;
    uint8_t started = 0;
    for (uint8_t i = 0; i < 10; i++) {
        uint32_t power = POWERS_OF_TEN[i];
        char digit = '0';
        while (value >= power) {
            value -= power;
            digit++;
        }
        if (digit != '0' || started || i == 9) {
            out[n++] = digit;
            started = 1;
        }
    }
    return n;
}

static char hex_digit(uint8_t nibble)
{
    return (char)(nibble < 10 ? '0' + nibble : 'A' + nibble - 10);
}

uint8_t lc1_checksum(const char *body, uint8_t n)
{
    uint8_t checksum = 0;
    for (uint8_t i = 0; i < n; i++)
        checksum ^= (uint8_t)body[i];
    return checksum;
}

uint8_t lc1_format_sample(char *out, uint16_t seq, uint32_t t_us, int32_t raw)
{
    uint8_t n = 0;
    out[n++] = '$';
    out[n++] = 'L';
    out[n++] = 'C';
    out[n++] = ',';
    n += put_decimal(out + n, seq);
    out[n++] = ',';
    n += put_decimal(out + n, t_us);
    out[n++] = ',';
    uint32_t magnitude = (uint32_t)raw;
    if (raw < 0) {
        out[n++] = '-';
        magnitude = 0U - magnitude; /* also right for -2^31 */
    }
    n += put_decimal(out + n, magnitude);
    uint8_t checksum = lc1_checksum(out + 1, (uint8_t)(n - 1));
    out[n++] = '*';
    out[n++] = hex_digit(checksum >> 4);
    out[n++] = hex_digit(checksum & 0x0F);
    out[n++] = '\r';
    out[n++] = '\n';
    return n;
}

uint8_t lc1_format_info(char *out, const char *text)
{
    uint8_t n = 0;
    out[n++] = '#';
    while (*text && n < LC1_MAX_INFO_BYTES - 2) {
        char c = *text++;
        out[n++] = (c < ' ' || c > '~' || c == '$' || c == '#') ? '?' : c;
    }
    out[n++] = '\r';
    out[n++] = '\n';
    return n;
}

int32_t hx711_sign_extend(uint32_t code)
{
    code &= 0x00FFFFFFUL;
    if (code & 0x00800000UL)
        code |= 0xFF000000UL;
    return (int32_t)code;
}

uint32_t capture_time_us(uint32_t overflows, uint16_t icr, uint8_t overflow_pending)
{
    /* An overflow that is pending while the captured count is in the lower half happened before
     * the capture; one pending with a count in the upper half came after it. */
    if (overflow_pending && icr < 0x8000U)
        overflows++;
    /* 65536 ticks of 0.5 us = 32768 us per overflow; unsigned arithmetic wraps at 2^32 us. */
    return (overflows << 15) + (uint32_t)(icr >> 1);
}

uint16_t rate_sps(uint32_t period_us)
{
    if (period_us == 0)
        return 0;
    return (uint16_t)((1000000UL + period_us / 2) / period_us);
}
