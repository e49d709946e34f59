/*
 * hx711-sim: runs the built firmware image (build/rig_hx711.elf) on simavr's ATmega328P at 16 MHz
 * with a model of the HX711 on D8 (DOUT) and D9 (PD_SCK), and puts the board's UART on a pty, so
 * the rig's driver (and `rig calibrate --port`) can read the real firmware before anything is
 * soldered. See firmware/README.md for the options and what is checked.
 *
 * The HX711 model (Avia Semiconductor HX711 datasheet, "Serial interface" and "Reset and power-down"):
 *   - a conversion completes every period (100 ms at RATE=0, 12.5 ms at RATE=1; 10/20/80/320 per
 *     second for the HX717); DOUT goes low when its result is ready;
 *   - each rising edge of PD_SCK shifts the next bit out on DOUT, MSB first, 24 bits; the 25th
 *     pulse pulls DOUT high again; 25, 26 or 27 pulses in a conversion period select channel A/128,
 *     B/32 or A/64 for the next conversion, other counts are a serial communication error;
 *   - PD_SCK high for more than 60 us powers the chip down; when PD_SCK returns low it resets
 *     (channel A, gain 128) and its first result comes after the settling time (4 periods: 400 ms
 *     at 10/s, 50 ms at 80/s); a high phase over 50 us breaks the T3 limit and is counted;
 *   - an unread result is replaced by the next one (the datasheet does not say; counted as missed);
 *   - the input is a count per conversion, clamped to the 24-bit range: out-of-range input gives
 *     the saturation codes 0x7FFFFF / 0x800000, as the datasheet says.
 *
 * It also watches every byte the UART sends: it parses the firmware's lines, checks each raw
 * against the value the model shifted out, and measures the latency from data-ready to the stop
 * bit of the line's last byte, in simulated time; `--stats FILE` writes these numbers as JSON.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <inttypes.h>
#include <libgen.h>
#include <limits.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/inotify.h>
#include <sys/ioctl.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "avr_ioport.h"
#include "avr_uart.h"
#include "sim_avr.h"
#include "sim_cycle_timers.h"
#include "sim_elf.h"
#include "sim_io.h"
#include "sim_irq.h"
#include "sim_time.h"

#define F_CPU_HZ 16000000UL
#define CYCLES_PER_US (F_CPU_HZ / 1000000UL)
#define COUNT_MAX 8388607L   /* 0x7FFFFF */
#define COUNT_MIN (-8388608L) /* 0x800000 as a signed 24-bit value */
#define POWER_DOWN_US 60
#define HIGH_MAX_US 50
#define SETTLING_PERIODS 4
/* ATmega328P data-space addresses of the UART0 registers (datasheet, "Register Summary"). */
#define UCSR0A_ADDR 0xC0
#define UBRR0L_ADDR 0xC4
#define UBRR0H_ADDR 0xC5
#define U2X0_MASK 0x02
#define BITS_PER_BYTE 10 /* 8N1 on the wire */
#define READ_RING 4096   /* reads remembered for matching lines to conversions */

static volatile sig_atomic_t stop_requested;
static int limit_reached; /* --lines or --seconds: wait for the reader before exiting */

static void on_signal(int signo)
{
    (void)signo;
    stop_requested = 1;
}

static void die(const char *message)
{
    fprintf(stderr, "hx711-sim: %s\n", message);
    exit(2);
}

/* ---- the input signal: counts per conversion ------------------------------------------------ */

enum signal_kind { SIGNAL_CONSTANT, SIGNAL_RAMP, SIGNAL_FILE, SIGNAL_STDIN };

typedef struct {
    enum signal_kind kind;
    int64_t constant;
    int64_t from, step, levels, hold; /* ramp: `levels` steps of `step` from `from`, each held `hold` conversions */
    int64_t *values;                  /* file: values and how many conversions each lasts */
    uint64_t *repeats;
    size_t count;
    size_t position;        /* file: current entry */
    uint64_t used;          /* file: conversions of the current entry already given */
    uint64_t index;         /* conversions given so far */
    char live[64];          /* stdin: the line still arriving */
    size_t live_len;
} input_signal_t;

static int64_t clamp_count(int64_t value)
{
    return value > COUNT_MAX ? COUNT_MAX : (value < COUNT_MIN ? COUNT_MIN : value);
}

static int parse_int64(const char *text, int64_t *out)
{
    char *end;
    errno = 0;
    long long value = strtoll(text, &end, 0);
    if (errno || end == text || *end)
        return -1;
    *out = value;
    return 0;
}

static void load_signal_file(input_signal_t *s, const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "hx711-sim: --signal file:%s: %s\n", path, strerror(errno));
        exit(2);
    }
    size_t capacity = 0;
    char line[256];
    unsigned line_no = 0;
    while (fgets(line, sizeof line, f)) {
        line_no++;
        char *hash = strchr(line, '#');
        if (hash)
            *hash = 0;
        char *first = strtok(line, " \t\r\n");
        if (!first)
            continue;
        char *second = strtok(NULL, " \t\r\n");
        int64_t value, repeat = 1;
        if (parse_int64(first, &value) || (second && (parse_int64(second, &repeat) || repeat < 1)) ||
            strtok(NULL, " \t\r\n")) {
            fprintf(stderr, "hx711-sim: %s line %u: expected COUNTS [REPEAT >= 1]\n", path, line_no);
            exit(2);
        }
        if (s->count == capacity) {
            capacity = capacity ? 2 * capacity : 64;
            s->values = realloc(s->values, capacity * sizeof *s->values);
            s->repeats = realloc(s->repeats, capacity * sizeof *s->repeats);
            if (!s->values || !s->repeats)
                die("out of memory");
        }
        s->values[s->count] = value;
        s->repeats[s->count] = (uint64_t)repeat;
        s->count++;
    }
    fclose(f);
    if (!s->count) {
        fprintf(stderr, "hx711-sim: %s: no counts in the file\n", path);
        exit(2);
    }
}

static void parse_signal(input_signal_t *s, const char *spec)
{
    memset(s, 0, sizeof *s);
    char copy[PATH_MAX + 16];
    snprintf(copy, sizeof copy, "%s", spec);
    if (!strncmp(copy, "constant:", 9)) {
        s->kind = SIGNAL_CONSTANT;
        if (parse_int64(copy + 9, &s->constant))
            die("--signal constant:COUNTS needs an integer");
        return;
    }
    if (!strcmp(copy, "stdin")) {
        s->kind = SIGNAL_STDIN; /* the latest whole line of counts read from stdin (read_live_signal) */
        fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
        return;
    }
    if (!strncmp(copy, "file:", 5)) {
        s->kind = SIGNAL_FILE;
        load_signal_file(s, copy + 5);
        return;
    }
    if (!strncmp(copy, "ramp:", 5)) {
        int64_t v[4] = {0, 0, 0, 1};
        int n = 0;
        for (char *field = strtok(copy + 5, ":"); field; field = strtok(NULL, ":")) {
            if (n == 4 || parse_int64(field, &v[n]))
                die("--signal ramp:FROM:TO:STEP[:HOLD] needs integers");
            n++;
        }
        if (n < 3 || v[2] == 0 || (v[1] - v[0]) / v[2] < 0 || v[3] < 1)
            die("--signal ramp:FROM:TO:STEP[:HOLD]: STEP must be non-zero and lead from FROM to TO; HOLD >= 1");
        s->kind = SIGNAL_RAMP;
        s->from = v[0];
        s->step = v[2];
        s->levels = (v[1] - v[0]) / v[2] + 1;
        s->hold = v[3];
        return;
    }
    die("--signal: allowed: constant:COUNTS, ramp:FROM:TO:STEP[:HOLD], file:PATH, stdin");
}

/* --signal stdin: take the lines that arrived since the last call; the last whole one is the input
 * from now on (a line that is not an integer is ignored). The end of stdin keeps the last value. */
static void read_live_signal(input_signal_t *s)
{
    if (s->kind != SIGNAL_STDIN)
        return;
    char chunk[4096];
    ssize_t n;
    while ((n = read(0, chunk, sizeof chunk)) > 0) {
        for (ssize_t i = 0; i < n; i++) {
            if (chunk[i] != '\n') {
                if (s->live_len < sizeof s->live - 1)
                    s->live[s->live_len++] = chunk[i];
                continue;
            }
            s->live[s->live_len] = 0;
            int64_t value;
            if (!parse_int64(s->live, &value))
                s->constant = value;
            s->live_len = 0;
        }
    }
}

/* The input of the next conversion, clamped to the ADC's range (saturation codes beyond it). */
static int32_t signal_next(input_signal_t *s)
{
    int64_t value = 0;
    switch (s->kind) {
    case SIGNAL_CONSTANT:
    case SIGNAL_STDIN:
        value = s->constant;
        break;
    case SIGNAL_RAMP:
        value = s->from + (int64_t)(((s->index / (uint64_t)s->hold) % (uint64_t)s->levels)) * s->step;
        break;
    case SIGNAL_FILE:
        value = s->values[s->position];
        if (++s->used >= s->repeats[s->position]) {
            s->used = 0;
            s->position = (s->position + 1) % s->count; /* the file repeats */
        }
        break;
    }
    s->index++;
    return (int32_t)clamp_count(value);
}

/* ---- the HX711 model ------------------------------------------------------------------------ */

typedef struct {
    uint64_t ready_cycle;
    uint64_t conversion;
    int32_t value;
} read_record_t;

typedef struct {
    avr_t *avr;
    avr_irq_t *dout_irq;
    input_signal_t signal;
    uint64_t period_cycles;
    int powered;
    int dout;
    int sck;
    int have_data;        /* a result is latched and its 24 bits not yet all shifted out */
    int32_t latched;
    uint64_t latched_conversion;
    uint64_t latched_ready_cycle;
    uint32_t shifted;     /* bits shifted out of the current result */
    int pulses;           /* PD_SCK pulses since the latest data-ready */
    uint64_t rise_cycle;
    int rise_not_ready; /* the latest rising edge came while no result was ready */
    FILE *log;
    read_record_t reads_ring[READ_RING];
    /* counts */
    uint64_t conversions, reads, missed, serial_errors, long_high, clock_while_busy, power_downs;
    uint64_t gain_a128, gain_other;
} hx711_t;

static void set_dout(hx711_t *m, int level)
{
    /* Declare the pin driven from outside: simavr would otherwise let the firmware's pull-up on D8
     * overwrite the level on every write to PORTB. */
    avr_ioport_external_t external = {.name = 'B', .mask = 1, .value = (unsigned)level};
    avr_ioctl(m->avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('B'), &external);
    m->dout = level;
    avr_raise_irq(m->dout_irq, (uint32_t)level);
}

/* What the previous conversion period's pulses selected. */
static void close_read(hx711_t *m)
{
    if (m->pulses >= 25 && m->pulses <= 27) {
        if (m->pulses == 25)
            m->gain_a128++;
        else
            m->gain_other++;
    } else if (m->pulses) {
        m->serial_errors++;
    }
    m->pulses = 0;
}

static avr_cycle_count_t conversion_done(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)avr;
    hx711_t *m = param;
    if (!m->powered)
        return 0;
    int32_t value = signal_next(&m->signal);
    uint64_t conversion = m->conversions++;
    if (m->pulses > 0 && m->pulses < 25) {
        m->serial_errors++; /* the MCU is in the middle of a read: this result is lost */
        return when + m->period_cycles;
    }
    if (m->have_data && m->pulses == 0)
        m->missed++; /* the previous result was never read */
    close_read(m);
    m->latched = value;
    m->latched_conversion = conversion;
    m->latched_ready_cycle = when;
    m->shifted = 0;
    m->have_data = 1;
    set_dout(m, 0);
    return when + m->period_cycles;
}

static avr_cycle_count_t power_down(avr_t *avr, avr_cycle_count_t when, void *param)
{
    (void)when;
    hx711_t *m = param;
    if (!m->sck || !m->powered)
        return 0;
    m->powered = 0;
    m->power_downs++;
    m->have_data = 0;
    m->pulses = 0;
    avr_cycle_timer_cancel(avr, conversion_done, m);
    set_dout(m, 1);
    return 0;
}

static void sck_changed(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    hx711_t *m = param;
    avr_t *avr = m->avr;
    int level = value ? 1 : 0;
    if (level == m->sck)
        return;
    m->sck = level;
    if (level) {
        m->rise_cycle = avr->cycle;
        avr_cycle_timer_cancel(avr, power_down, m);
        avr_cycle_timer_register(avr, POWER_DOWN_US * CYCLES_PER_US, power_down, m);
        if (!m->powered)
            return;
        m->rise_not_ready = !m->have_data && m->pulses == 0;
        if (m->rise_not_ready)
            return;
        m->pulses++;
        if (m->pulses <= 24) {
            int bit = (int)(((uint32_t)m->latched >> (24 - m->pulses)) & 1U);
            m->shifted = (m->shifted << 1) | (uint32_t)bit;
            set_dout(m, bit);
            if (m->pulses == 24) {
                int32_t value = (int32_t)(m->shifted & 0x800000U ? m->shifted | 0xFF000000U : m->shifted);
                read_record_t *r = &m->reads_ring[m->reads % READ_RING];
                r->ready_cycle = m->latched_ready_cycle;
                r->conversion = m->latched_conversion;
                r->value = value;
                m->reads++;
                m->have_data = 0;
                if (m->log)
                    fprintf(m->log, "%" PRIu64 " %" PRIu64 " %" PRId32 "\n", m->latched_conversion,
                            m->latched_ready_cycle, value);
            }
        } else if (m->pulses == 25) {
            set_dout(m, 1);
        }
        return;
    }
    avr_cycle_timer_cancel(avr, power_down, m);
    uint64_t high_cycles = avr->cycle - m->rise_cycle;
    if (m->powered && high_cycles > HIGH_MAX_US * CYCLES_PER_US)
        m->long_high++;
    if (m->powered && m->rise_not_ready)
        m->clock_while_busy++; /* a pulse while no result was ready (and not a power-down) */
    if (!m->powered) {
        /* Back from power-down: reset to channel A, gain 128; first result after settling. */
        m->powered = 1;
        m->pulses = 0;
        avr_cycle_timer_cancel(avr, conversion_done, m);
        avr_cycle_timer_register(avr, SETTLING_PERIODS * m->period_cycles, conversion_done, m);
    }
}

/* --reset-on-open: every open(2) and close of the pty's slave by a client, whichever path it came
 * by, as Linux inotify events on the device node (pyserial asserts DTR on open, which resets an Uno
 * through its auto-reset capacitor). The harness's own descriptors are opened before the watch. */
typedef struct {
    int fd; /* -1: not watching */
    int clients; /* clients that have the port open */
    int open_pending; /* a client opened it and the board has not been reset for it yet */
} open_watch_t;

static open_watch_t opens = {.fd = -1};

static void watch_client_opens(const char *device)
{
    int fd = inotify_init1(IN_NONBLOCK);
    if (fd >= 0 && inotify_add_watch(fd, device, IN_OPEN | IN_CLOSE_WRITE | IN_CLOSE_NOWRITE) < 0) {
        close(fd);
        fd = -1;
    }
    opens.fd = fd;
}

static void poll_client_opens(void)
{
    char events[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
    ssize_t n;
    while (opens.fd >= 0 && (n = read(opens.fd, events, sizeof events)) > 0) {
        for (char *p = events; p < events + n;) {
            const struct inotify_event *event = (const struct inotify_event *)p;
            if (event->mask & IN_OPEN) {
                opens.clients++;
                opens.open_pending = 1;
            }
            if ((event->mask & (IN_CLOSE_WRITE | IN_CLOSE_NOWRITE)) && opens.clients > 0)
                opens.clients--;
            p += sizeof *event + event->len;
        }
    }
}

/* While nobody has the port open (or an open has not reset the board yet), what the board sends is
 * lost, as into a USB adapter whose port is closed: no line of an old boot reaches a new client. */
static int board_output_lost(void)
{
    if (opens.fd < 0)
        return 0;
    poll_client_opens();
    return opens.clients == 0 || opens.open_pending;
}

/* The board resets (its RESET pin pulled low by DTR): the MCU starts again from its reset vector with
 * its registers cleared; the HX711 is not reset by it, but its pending result is dropped and the
 * conversion timer (cleared with simavr's cycle timers) is armed again. */
static void reset_board(hx711_t *m)
{
    avr_reset(m->avr);
    m->have_data = 0;
    m->pulses = 0;
    m->shifted = 0;
    m->sck = 0;
    m->powered = 1;
    set_dout(m, 1);
    avr_cycle_timer_register(m->avr, m->period_cycles, conversion_done, m);
}

/* ---- the UART: a pty for the host, and a tap that checks and times every line ---------------- */

typedef struct {
    hx711_t *model;
    int master_fd;
    int slave_fd; /* the harness's own descriptor of the pty's slave: the client's termios, for its baud */
    uint64_t wrong_baud_bytes;
    int block; /* --fast: wait for the reader instead of dropping bytes */
    char out[4096];
    size_t out_len;
    uint64_t bytes_out, pty_bytes_dropped;
    /* line parsing */
    char line[128];
    size_t line_len;
    int have_offset;
    int64_t read_offset; /* read index = unwrapped seq + offset */
    int64_t seq_unwrapped;
    uint16_t last_seq;
    int have_seq;
    uint32_t last_t_us;
    uint64_t last_ready_cycle;
    /* counts */
    uint64_t lines, info_lines, banners, bad_lines, mismatches, seq_gaps, unmatched;
    int64_t t_step_min, t_step_max, ready_step_min_cycles, ready_step_max_cycles;
    int64_t t_vs_ready_max_us; /* max |t-us step - data-ready step| */
    uint64_t latency_min, latency_max, latency_sum, latency_count; /* cycles */
    uint64_t line_limit;
} uart_tap_t;

static uint32_t bit_cycles(avr_t *avr);

/* The baud rate the client set on the pty (0: unknown, e.g. no descriptor to ask). */
static long client_baud(int slave_fd)
{
    struct termios tio;
    if (slave_fd < 0 || tcgetattr(slave_fd, &tio))
        return 0;
    static const struct {
        speed_t code;
        long baud;
    } speeds[] = {{B9600, 9600},     {B19200, 19200},   {B38400, 38400},     {B57600, 57600},
                  {B115200, 115200}, {B230400, 230400}, {B460800, 460800},   {B500000, 500000},
                  {B576000, 576000}, {B921600, 921600}, {B1000000, 1000000}, {B2000000, 2000000}};
    speed_t code = cfgetospeed(&tio);
    for (size_t i = 0; i < sizeof speeds / sizeof speeds[0]; i++)
        if (speeds[i].code == code)
            return speeds[i].baud;
    return -1;
}

/* A UART receiving at another rate than the sender's sees framing garbage, never a line: the same
 * mapping as the Python emulator's (rig/sim/loadcell/emulator.py, wrong_baud_garbage). Two rates
 * within 5 % of each other are the same rate (115200 from a 16 MHz clock with U2X is 117647). */
static void garble_if_wrong_baud(uart_tap_t *u)
{
    long client = client_baud(u->slave_fd);
    uint32_t cycles = bit_cycles(u->model->avr);
    if (client == 0 || cycles == 0)
        return;
    double board = (double)F_CPU_HZ / (double)cycles;
    if (client > 0 && client > 0.95 * board && client < 1.05 * board)
        return;
    for (size_t i = 0; i < u->out_len; i++)
        u->out[i] = (char)((((unsigned char)u->out[i] * 37u + 11u) & 0x7Fu) | 0x80u);
    u->wrong_baud_bytes += u->out_len;
}

static void flush_out(uart_tap_t *u)
{
    size_t done = 0;
    if (board_output_lost()) {
        u->bytes_out += u->out_len;
        u->pty_bytes_dropped += u->out_len;
        u->out_len = 0;
        return;
    }
    garble_if_wrong_baud(u);
    while (u->master_fd >= 0 && done < u->out_len) {
        ssize_t n = write(u->master_fd, u->out + done, u->out_len - done);
        if (n > 0) {
            done += (size_t)n;
            continue;
        }
        if (n < 0 && (errno == EAGAIN || errno == EINTR) && u->block && !stop_requested) {
            struct pollfd p = {.fd = u->master_fd, .events = POLLOUT};
            poll(&p, 1, 100);
            continue;
        }
        break;
    }
    u->bytes_out += u->out_len;
    u->pty_bytes_dropped += u->out_len - done;
    u->out_len = 0;
}

static int parse_u64_field(const char **p, uint64_t *out)
{
    const char *s = *p;
    if (*s < '0' || *s > '9')
        return -1;
    uint64_t v = 0;
    while (*s >= '0' && *s <= '9')
        v = v * 10 + (uint64_t)(*s++ - '0');
    *p = s;
    *out = v;
    return 0;
}

static uint32_t bit_cycles(avr_t *avr)
{
    uint32_t ubrr = avr->data[UBRR0L_ADDR] | ((uint32_t)avr->data[UBRR0H_ADDR] << 8);
    return (ubrr + 1) * ((avr->data[UCSR0A_ADDR] & U2X0_MASK) ? 8 : 16);
}

static void data_line(uart_tap_t *u, const char *text, uint64_t end_cycle)
{
    /* $LC,<seq>,<t-us>,<raw>*hh */
    const char *p = text + 4;
    uint64_t seq, t_us, magnitude;
    int negative = 0;
    if (parse_u64_field(&p, &seq) || *p++ != ',' || parse_u64_field(&p, &t_us) || *p++ != ',') {
        u->bad_lines++;
        return;
    }
    if (*p == '-') {
        negative = 1;
        p++;
    }
    if (parse_u64_field(&p, &magnitude) || *p != '*') {
        u->bad_lines++;
        return;
    }
    int64_t raw = negative ? -(int64_t)magnitude : (int64_t)magnitude;
    u->lines++;
    if (u->have_seq) {
        uint16_t step = (uint16_t)((uint16_t)seq - u->last_seq);
        if (step != 1)
            u->seq_gaps++;
        u->seq_unwrapped += step;
    } else {
        u->seq_unwrapped = (int64_t)seq;
    }
    u->have_seq = 1;
    u->last_seq = (uint16_t)seq;
    hx711_t *m = u->model;
    if (!u->have_offset) {
        /* The first line after a boot: t-us counts from when the firmware started Timer1, early in
         * setup(), so its read is the one whose data-ready time is the least at or after t-us
         * (earlier reads come a whole period or more before, later ones after). Then seq counts on. */
        int64_t best = -1, best_gap = INT64_MAX;
        for (uint64_t r = m->reads > READ_RING ? m->reads - READ_RING : 0; r < m->reads; r++) {
            int64_t gap = (int64_t)(m->reads_ring[r % READ_RING].ready_cycle / CYCLES_PER_US) - (int64_t)t_us;
            if (gap >= 0 && gap < best_gap) {
                best_gap = gap;
                best = (int64_t)r;
            }
        }
        if (best < 0) {
            u->unmatched++;
            return;
        }
        u->read_offset = best - u->seq_unwrapped;
        u->have_offset = 1;
    }
    int64_t read_index = u->seq_unwrapped + u->read_offset;
    if (read_index < 0 || (uint64_t)read_index >= m->reads || m->reads - (uint64_t)read_index > READ_RING) {
        u->unmatched++;
        return;
    }
    read_record_t *r = &m->reads_ring[read_index % READ_RING];
    if (r->value != raw)
        u->mismatches++;
    uint64_t latency = end_cycle - r->ready_cycle;
    if (!u->latency_count || latency < u->latency_min)
        u->latency_min = latency;
    if (latency > u->latency_max)
        u->latency_max = latency;
    u->latency_sum += latency;
    u->latency_count++;
    if (u->lines > 1) {
        int64_t t_step = (int64_t)(uint32_t)((uint32_t)t_us - u->last_t_us);
        int64_t ready_step = (int64_t)(r->ready_cycle - u->last_ready_cycle);
        if (u->lines == 2 || t_step < u->t_step_min)
            u->t_step_min = t_step;
        if (u->lines == 2 || t_step > u->t_step_max)
            u->t_step_max = t_step;
        if (u->lines == 2 || ready_step < u->ready_step_min_cycles)
            u->ready_step_min_cycles = ready_step;
        if (u->lines == 2 || ready_step > u->ready_step_max_cycles)
            u->ready_step_max_cycles = ready_step;
        /* Compared in cycles (16 per us) so the difference is not rounded before it is taken. */
        int64_t off_cycles = t_step * (int64_t)CYCLES_PER_US - ready_step;
        int64_t off_us = (off_cycles < 0 ? -off_cycles : off_cycles + (int64_t)CYCLES_PER_US - 1) /
                         (int64_t)CYCLES_PER_US;
        if (off_us > u->t_vs_ready_max_us)
            u->t_vs_ready_max_us = off_us;
    }
    u->last_t_us = (uint32_t)t_us;
    u->last_ready_cycle = r->ready_cycle;
}

static void uart_byte(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    uart_tap_t *u = param;
    avr_t *avr = u->model->avr;
    char c = (char)value;
    if (u->out_len == sizeof u->out)
        flush_out(u);
    u->out[u->out_len++] = c;
    if (u->line_len < sizeof u->line - 1)
        u->line[u->line_len++] = c;
    if (c != '\n')
        return;
    flush_out(u);
    /* The byte was written to UDR now; its stop bit leaves the pin 10 bit times later. */
    uint64_t end_cycle = avr->cycle + (uint64_t)BITS_PER_BYTE * bit_cycles(avr);
    u->line[u->line_len] = 0;
    if (u->line[0] == '#') {
        u->info_lines++;
        if (!strncmp(u->line, "#BOOT", 5)) {
            u->banners++;
            u->have_offset = 0; /* seq starts again */
            u->have_seq = 0;
        }
        fprintf(stderr, "hx711-sim: firmware says %.*s\n", (int)strcspn(u->line, "\r\n"), u->line);
    } else if (!strncmp(u->line, "$LC,", 4)) {
        data_line(u, u->line, end_cycle);
        if (u->line_limit && u->lines >= u->line_limit)
            stop_requested = limit_reached = 1;
    } else {
        u->bad_lines++;
    }
    u->line_len = 0;
}

/* ---- the pty ---------------------------------------------------------------------------------- */

static int open_pty(const char *link, char *device, size_t device_size, int *slave_fd)
{
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) || unlockpt(master))
        die("cannot open a pty");
    const char *name = ptsname(master);
    if (!name)
        die("cannot name the pty");
    snprintf(device, device_size, "%s", name);
    int slave = open(device, O_RDWR | O_NOCTTY);
    if (slave < 0)
        die("cannot open the pty's slave side");
    struct termios tio;
    tcgetattr(slave, &tio);
    cfmakeraw(&tio);
    cfsetispeed(&tio, B115200);
    cfsetospeed(&tio, B115200);
    tcsetattr(slave, TCSANOW, &tio);
    *slave_fd = slave;
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    if (link) {
        struct stat st;
        if (lstat(link, &st) == 0) {
            if (!S_ISLNK(st.st_mode)) {
                fprintf(stderr, "hx711-sim: --link %s exists and is not a symlink; allowed: a new path or an old link\n",
                        link);
                exit(2);
            }
            unlink(link);
        }
        if (symlink(device, link)) {
            fprintf(stderr, "hx711-sim: --link %s: %s\n", link, strerror(errno));
            exit(2);
        }
    }
    return master;
}

/* Wait until a client has the pty open (the master stops reporting a hang-up), as a real board
 * starts when the host opens its port (DTR resets it). */
static void wait_for_client(int master, int *slave_fd)
{
    close(*slave_fd);
    *slave_fd = -1;
    while (!stop_requested) {
        struct pollfd p = {.fd = master, .events = POLLIN};
        if (poll(&p, 1, 50) >= 0 && !(p.revents & POLLHUP))
            return;
        usleep(5000);
    }
}

static void drain_host_input(int master)
{
    char scratch[256];
    while (read(master, scratch, sizeof scratch) > 0) {
    } /* the firmware ignores what the host sends; keep the host's writes from filling the pty */
}

/* ---- main ------------------------------------------------------------------------------------- */

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
    (void)avr;
    (void)how_long; /* pacing is done in main(), or not at all with --fast */
}

static uint64_t now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ULL + (uint64_t)ts.tv_nsec;
}

static void usage(FILE *to)
{
    fprintf(to,
            "usage: hx711-sim [--firmware ELF] [--link PATH] [--rate 10|20|80|320] [--period-us N]\n"
            "                 [--signal constant:COUNTS | ramp:FROM:TO:STEP[:HOLD] | file:PATH | stdin]\n"
            "                 [--fast] [--wait-open] [--reset-on-open MS] [--seconds S] [--lines N] [--log FILE]\n"
            "                 [--stats FILE]\n"
            "Runs the rig-lc1 HX711 firmware on simavr (ATmega328P, 16 MHz) with an HX711 model on D8/D9\n"
            "and its UART on a pty (printed as `PTY <link> <device>`). Real time unless --fast.\n"
            "  --rate        conversions per second: 10 or 80 (HX711 RATE pin), 20 or 320 (HX717) (default 80)\n"
            "  --period-us   conversion period in us instead of the nominal one (a slow or fast oscillator)\n"
            "  --signal      the ADC input per conversion (default constant:0); ramp: a staircase from FROM\n"
            "                to TO in STEPs, each held HOLD conversions, repeating; file: one `COUNTS [REPEAT]`\n"
            "                per line, repeating; stdin: the latest whole line of counts on stdin (live);\n"
            "                beyond 24 bits the ADC saturates (0x7FFFFF / 0x800000)\n"
            "A client whose baud differs from the firmware's by more than 5 %% receives garbage, as from a UART.\n"
            "  --fast        run as fast as the host allows; the pty then waits for its reader (no bytes lost)\n"
            "  --wait-open   start the board 0.2 s after a client opens the pty (as DTR resets a real one)\n"
            "  --reset-on-open MS  reset the board on every open of the pty by a client, silent for MS ms\n"
            "                (the bootloader's wait; optiboot on an Uno: about 1500) before the sketch starts\n"
            "  --seconds S   stop after S simulated seconds;  --lines N  stop after N data lines\n"
            "  --log FILE    one line per conversion read: `conversion ready_cycle value` (what was shifted out)\n"
            "  --stats FILE  JSON with the counts, t-us steps and latencies at exit (also on SIGTERM/SIGINT)\n");
}

int main(int argc, char **argv)
{
    const char *firmware = NULL, *link = NULL, *signal_spec = "constant:0", *log_path = NULL, *stats_path = NULL;
    long rate = 80, period_us = 0;
    double seconds = 0;
    long long line_limit = 0;
    int fast = 0, wait_open = 0;
    long reset_on_open_ms = -1;
    static struct option options[] = {
        {"firmware", required_argument, 0, 'f'}, {"link", required_argument, 0, 'l'},
        {"rate", required_argument, 0, 'r'},     {"period-us", required_argument, 0, 'p'},
        {"signal", required_argument, 0, 's'},   {"fast", no_argument, 0, 'F'},
        {"wait-open", no_argument, 0, 'w'},      {"seconds", required_argument, 0, 'S'},
        {"lines", required_argument, 0, 'n'},    {"log", required_argument, 0, 'L'},
        {"stats", required_argument, 0, 'j'},    {"help", no_argument, 0, 'h'},
        {"reset-on-open", required_argument, 0, 'R'},
        {0, 0, 0, 0},
    };
    int opt;
    while ((opt = getopt_long(argc, argv, "", options, NULL)) != -1) {
        char *end = NULL;
        switch (opt) {
        case 'f': firmware = optarg; break;
        case 'l': link = optarg; break;
        case 'r':
            rate = strtol(optarg, &end, 10);
            if (*end || (rate != 10 && rate != 20 && rate != 80 && rate != 320))
                die("--rate: allowed: 10, 80 (HX711), 20, 320 (HX717)");
            break;
        case 'p':
            period_us = strtol(optarg, &end, 10);
            if (*end || period_us < 1000 || period_us > 1000000)
                die("--period-us: allowed: 1000-1000000");
            break;
        case 's': signal_spec = optarg; break;
        case 'F': fast = 1; break;
        case 'w': wait_open = 1; break;
        case 'R':
            reset_on_open_ms = strtol(optarg, &end, 10);
            if (*end || reset_on_open_ms < 0 || reset_on_open_ms > 10000)
                die("--reset-on-open: allowed: 0-10000 (ms the bootloader waits before the sketch starts)");
            break;
        case 'S':
            seconds = strtod(optarg, &end);
            if (*end || !(seconds > 0 && seconds < 1e7))
                die("--seconds: allowed: > 0 and < 1e7");
            break;
        case 'n':
            line_limit = strtoll(optarg, &end, 10);
            if (*end || line_limit < 1)
                die("--lines: allowed: >= 1");
            break;
        case 'L': log_path = optarg; break;
        case 'j': stats_path = optarg; break;
        case 'h': usage(stdout); return 0;
        default: usage(stderr); return 2;
        }
    }
    if (optind != argc) {
        usage(stderr);
        return 2;
    }
    char default_firmware[PATH_MAX];
    if (!firmware) {
        char self[PATH_MAX];
        ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
        if (n <= 0)
            die("cannot find the firmware next to the harness; pass --firmware ELF");
        self[n] = 0;
        snprintf(default_firmware, sizeof default_firmware, "%s/rig_hx711.elf", dirname(self));
        firmware = default_firmware;
    }
    if (access(firmware, R_OK)) {
        fprintf(stderr, "hx711-sim: --firmware %s: %s (build it with `make -C firmware`)\n", firmware,
                strerror(errno));
        return 2;
    }

    static hx711_t model;
    parse_signal(&model.signal, signal_spec);
    if (!period_us)
        period_us = 1000000L / rate;
    model.period_cycles = (uint64_t)period_us * CYCLES_PER_US;
    if (log_path && !(model.log = fopen(log_path, "w"))) {
        fprintf(stderr, "hx711-sim: --log %s: %s\n", log_path, strerror(errno));
        return 2;
    }

    elf_firmware_t f;
    memset(&f, 0, sizeof f);
    fflush(stdout);
    int saved_stdout = dup(1), null_fd = open("/dev/null", O_WRONLY);
    dup2(null_fd, 1); /* simavr's loader prints "Loaded ..." there; stdout is for the PTY line */
    int elf_failed = elf_read_firmware(firmware, &f);
    f.frequency = F_CPU_HZ; /* an Arduino ELF carries no .mmcu section */
    snprintf(f.mmcu, sizeof f.mmcu, "atmega328p");
    if (elf_failed)
        die("cannot read the firmware ELF");
    avr_t *avr = avr_make_mcu_by_name("atmega328p");
    if (!avr)
        die("simavr has no atmega328p");
    avr_init(avr);
    avr_load_firmware(avr, &f);
    fflush(stdout);
    dup2(saved_stdout, 1);
    close(saved_stdout);
    close(null_fd);
    avr->frequency = F_CPU_HZ;
    avr->sleep = no_sleep;
    avr->log = 0;

    model.avr = avr;
    model.dout_irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 0);
    model.powered = 1;
    model.sck = 0;
    set_dout(&model, 1);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('B'), 1), sck_changed, &model);
    avr_cycle_timer_register(avr, model.period_cycles, conversion_done, &model);

    static uart_tap_t tap;
    tap.model = &model;
    tap.block = fast;
    tap.line_limit = (uint64_t)line_limit;
    uint32_t uart_flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &uart_flags);
    /* No console printing, and no usleep() each time the firmware reads UCSR0A while idle. */
    uart_flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &uart_flags);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), uart_byte, &tap);

    char device[128];
    int slave_fd = -1;
    tap.master_fd = open_pty(link, device, sizeof device, &slave_fd);
    tap.slave_fd = slave_fd;
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    printf("PTY %s %s rate=%ld period-us=%ld signal=%s%s\n", link ? link : device, device, rate, period_us,
           signal_spec, fast ? " fast" : "");
    fflush(stdout);
    if (wait_open) {
        wait_for_client(tap.master_fd, &slave_fd);
        usleep(200000);
        slave_fd = open(device, O_RDWR | O_NOCTTY); /* hold it: a client's close must not hang up the pty */
        tap.slave_fd = slave_fd;
    }
    if (reset_on_open_ms >= 0) {
        watch_client_opens(device);
        if (opens.fd < 0)
            die("--reset-on-open: cannot watch the pty for opens (inotify)");
    }
    uint64_t resets = 0;

    const uint64_t check_cycles = F_CPU_HZ / 1000; /* pace and poll every simulated millisecond */
    uint64_t next_check = avr->cycle + check_cycles;
    uint64_t end_cycle = seconds > 0 ? (uint64_t)(seconds * (double)F_CPU_HZ) : UINT64_MAX;
    uint64_t wall_start = now_ns();
    int state = cpu_Running;
    while (!stop_requested && avr->cycle < end_cycle) {
        state = avr_run(avr);
        if (state == cpu_Done || state == cpu_Crashed)
            break;
        if (avr->cycle >= next_check) {
            next_check = avr->cycle + check_cycles;
            drain_host_input(tap.master_fd);
            read_live_signal(&model.signal);
            poll_client_opens();
            if (opens.open_pending) {
                /* The bootloader (optiboot) holds the board silent for a while, then starts the
                 * sketch; the pacing restarts from the wall clock so nothing comes in a burst. */
                tap.out_len = 0; /* the rest of a line the old boot was sending */
                tap.line_len = 0;
                resets++;
                struct timespec hold = {reset_on_open_ms / 1000, (reset_on_open_ms % 1000) * 1000000L};
                nanosleep(&hold, NULL);
                poll_client_opens(); /* an open during the hold resets a board that is resetting */
                opens.open_pending = 0;
                reset_board(&model);
                wall_start = now_ns() - avr_cycles_to_nsec(avr, avr->cycle);
                next_check = avr->cycle + check_cycles;
            }
            if (!fast) {
                uint64_t sim_ns = avr_cycles_to_nsec(avr, avr->cycle);
                uint64_t wall_ns = now_ns() - wall_start;
                if (sim_ns > wall_ns + 1000000ULL) {
                    struct timespec ts = {(time_t)((sim_ns - wall_ns) / 1000000000ULL),
                                          (long)((sim_ns - wall_ns) % 1000000000ULL)};
                    nanosleep(&ts, NULL);
                }
            }
        }
    }
    if (avr->cycle >= end_cycle)
        limit_reached = 1;
    double wall_s = (double)(now_ns() - wall_start) / 1e9;
    flush_out(&tap);
    /* Give the reader up to 2 s to take what is still in the pty before it goes away: the kernel
     * moves bytes from the master to the slave's queue a little later, so the queue must stay
     * empty for 60 ms. */
    if (slave_fd >= 0 && limit_reached) {
        int quiet = 0;
        for (int i = 0; i < 100 && quiet < 3; i++) {
            usleep(20000);
            int pending = 0;
            if (ioctl(slave_fd, FIONREAD, &pending))
                break;
            quiet = pending ? 0 : quiet + 1;
        }
    }
    if (model.log)
        fclose(model.log);
    double sim_s = (double)avr->cycle / (double)F_CPU_HZ;
    double per_cycle_us = 1.0 / (double)CYCLES_PER_US;
    FILE *out = stats_path ? fopen(stats_path, "w") : NULL;
    if (stats_path && !out)
        fprintf(stderr, "hx711-sim: --stats %s: %s\n", stats_path, strerror(errno));
    char stats[4096];
    snprintf(stats, sizeof stats,
             "{\"rate_sps\": %ld, \"period_us\": %ld, \"signal\": \"%s\", \"fast\": %s,\n"
             " \"sim_seconds\": %.6f, \"wall_seconds\": %.3f, \"speed_x_real_time\": %.2f, \"cpu_state\": %d,\n"
             " \"conversions\": %" PRIu64 ", \"reads\": %" PRIu64 ", \"missed_conversions\": %" PRIu64
             ", \"serial_errors\": %" PRIu64 ", \"long_high_phases\": %" PRIu64
             ", \"clock_while_not_ready\": %" PRIu64 ", \"power_downs\": %" PRIu64
             ", \"reads_gain_a128\": %" PRIu64 ", \"reads_other_gain\": %" PRIu64 ",\n"
             " \"data_lines\": %" PRIu64 ", \"info_lines\": %" PRIu64 ", \"banners\": %" PRIu64
             ", \"bad_lines\": %" PRIu64 ", \"raw_mismatches\": %" PRIu64 ", \"unmatched_lines\": %" PRIu64
             ", \"seq_gaps\": %" PRIu64 ",\n"
             " \"t_us_step_min\": %" PRId64 ", \"t_us_step_max\": %" PRId64
             ", \"ready_step_min_us\": %.4f, \"ready_step_max_us\": %.4f, \"t_us_vs_ready_step_max_us\": %" PRId64
             ",\n"
             " \"latency_us_min\": %.3f, \"latency_us_mean\": %.3f, \"latency_us_max\": %.3f,\n"
             " \"bytes_out\": %" PRIu64 ", \"pty_bytes_dropped\": %" PRIu64 ", \"wrong_baud_bytes\": %" PRIu64
             ", \"resets_on_open\": %" PRIu64 "}\n",
             rate, period_us, signal_spec, fast ? "true" : "false", sim_s, wall_s, wall_s > 0 ? sim_s / wall_s : 0.0,
             state, model.conversions, model.reads, model.missed, model.serial_errors, model.long_high,
             model.clock_while_busy, model.power_downs, model.gain_a128, model.gain_other, tap.lines,
             tap.info_lines, tap.banners, tap.bad_lines, tap.mismatches, tap.unmatched, tap.seq_gaps,
             tap.t_step_min, tap.t_step_max, (double)tap.ready_step_min_cycles * per_cycle_us,
             (double)tap.ready_step_max_cycles * per_cycle_us, tap.t_vs_ready_max_us,
             (double)tap.latency_min * per_cycle_us,
             tap.latency_count ? (double)tap.latency_sum / (double)tap.latency_count * per_cycle_us : 0.0,
             (double)tap.latency_max * per_cycle_us, tap.bytes_out, tap.pty_bytes_dropped, tap.wrong_baud_bytes,
             resets);
    if (out) {
        fputs(stats, out);
        fclose(out);
    }
    fputs(stats, stderr);
    if (link)
        unlink(link);
    return state == cpu_Crashed ? 1 : 0;
}
