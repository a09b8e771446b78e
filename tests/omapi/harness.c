/*
 * Drives one device through Axivity's OmApi in OMGui's order (stillpoint's test code).
 *
 *   harness SERIAL PORT VOLUME DOWNLOAD SESSION METADATA RATE RANGE GYRO DEBUG
 *
 * SERIAL/PORT/VOLUME are what the device finder reports (finder.c); DOWNLOAD is the file the full
 * download is written to; SESSION, METADATA, RATE (Hz), RANGE (g), GYRO (dps, 0: none) and DEBUG
 * are the settings of OMGui's Record dialog.
 *
 * Phases, each call as OMGui makes it (Software/OM/omgui/MainForm.cs, Software/OM/omapinet/
 * OmDevice.cs in digitalinteraction/openmovement):
 *   read      the calls OMGui makes to show a device;
 *   download  OmBeginDownloading(id, 0, -1, file) + OmWaitForDownload;
 *   clear     OmDevice.Clear(wipe=false), OmDevice.cs 610-625: session 0, blank metadata,
 *             "never log" delays, default accel config, OmEraseDataAndCommit(QUICKFORMAT);
 *             then read back what the data file holds;
 *   record    MainForm.cs 1784-1885: session, metadata, max samples 0, accel config, SyncTime
 *             (OmDevice.cs 432-479), DEBUG, SetInterval = OmSetDelays + OmCommit (OmDevice.cs
 *             550-567); then each setting read back through OmApi and from the data file's header.
 *
 * Output: one line per call, "<phase> <call> rc=<n> [key=value ...] unread=<bytes>", where rc is 0
 * when the call succeeded (OmApi returned a value >= 0, printed as value= where it is one) and
 * otherwise OmApi's negative OM_E_* code; values contain no spaces (strings escaped: \r, \n, \\,
 * \xNN for space and anything else outside printable ASCII); unread holds the bytes still waiting
 * on the port once the call has returned (the harness takes them off the port so that each call
 * is judged on its own). After OmCommit, whose reply OmApi takes from the first of the firmware's
 * two lines ("COMMIT: Delayed activation."), the harness first waits (at most 10 s) for the
 * second ("COMMIT", printed once the drive is back) and reports it as late=. A "header" line is
 * the harness reading the data file's header fields itself. DEBUG is sent through OmCommand as
 * OmDevice.SetDebug does (OmDevice.cs 603-608), but with the response buffer's real size (OMGui
 * passes a new StringBuilder's Length, 0, so no line can match and OmCommand waits out its 2 s).
 * Exit status 0 once every phase has run, 2 on bad arguments or set-up.
 */

#define _DEFAULT_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/time.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "omapi.h"

#include "finder.h"

#define SETTLE_US 30000              /* time given to a reply's trailing bytes to arrive */
#define DRIVE_WAIT_MS 10000          /* the longest the drive may take to come back */
#define DOWNLOAD_WAIT_MS 30000

static const char *port_path;
static const char *volume_path;
static char data_file[1024];
static char line[8192];
static size_t line_len;

/* ------------------------------------------------------------------ output */

static void add(const char *fmt, ...)
{
    va_list args;
    va_start(args, fmt);
    int n = vsnprintf(line + line_len, sizeof(line) - line_len, fmt, args);
    va_end(args);
    if (n > 0) {
        line_len += (size_t)n;
        if (line_len >= sizeof(line)) { line_len = sizeof(line) - 1; }
    }
}

static void add_escaped(const char *key, const unsigned char *s, size_t n)
{
    add(" %s=", key);
    for (size_t i = 0; i < n; i++) {
        unsigned char c = s[i];
        if (c == '\r') { add("\\r"); }
        else if (c == '\n') { add("\\n"); }
        else if (c == '\\') { add("\\\\"); }
        else if (c > ' ' && c < 0x7f) { add("%c", c); }
        else { add("\\x%02x", c); }
    }
}

static void add_string(const char *key, const char *s)
{
    add_escaped(key, (const unsigned char *)s, strlen(s));
}

static void add_time(const char *key, OM_DATETIME t)
{
    if (t < OM_DATETIME_MIN_VALID) { add(" %s=0", key); }
    else if (t > OM_DATETIME_MAX_VALID) { add(" %s=-1", key); }
    else {
        add(" %s=%04u-%02u-%02uT%02u:%02u:%02u", key, OM_DATETIME_YEAR(t), OM_DATETIME_MONTH(t),
            OM_DATETIME_DAY(t), OM_DATETIME_HOURS(t), OM_DATETIME_MINUTES(t), OM_DATETIME_SECONDS(t));
    }
}

static void begin(const char *phase, const char *call, int rc)
{
    line_len = 0;
    line[0] = '\0';
    add("%s %s rc=%d", phase, call, rc < 0 ? rc : 0);
}

/* ------------------------------------------------------------------ the port and the drive */

static long long now_ms(void)
{
    struct timeval tv;
    gettimeofday(&tv, NULL);
    return (long long)tv.tv_sec * 1000 + tv.tv_usec / 1000;
}

/* Take every byte waiting on the port (after SETTLE_US) into buf; returns the count. */
static size_t take_pending(unsigned char *buf, size_t size)
{
    size_t n = 0;
    int fd = open(port_path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) { return 0; }
    usleep(SETTLE_US);
    for (;;) {
        ssize_t r = read(fd, buf + n, size - n);
        if (r <= 0 || n + (size_t)r >= size) { if (r > 0) { n += (size_t)r; } break; }
        n += (size_t)r;
    }
    close(fd);
    return n;
}

/* Read the port until a line that is exactly `want` has arrived or timeout_ms passed. */
static size_t take_line(const char *want, unsigned char *buf, size_t size, long long timeout_ms)
{
    size_t n = 0;
    size_t want_len = strlen(want);
    long long end = now_ms() + timeout_ms;
    int fd = open(port_path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) { return 0; }
    while (now_ms() < end && n < size - 1) {
        ssize_t r = read(fd, buf + n, size - 1 - n);
        if (r > 0) {
            n += (size_t)r;
            buf[n] = '\0';
            const char *p = (const char *)buf;
            int found = 0;
            while (p != NULL && *p != '\0') {
                if (strncmp(p, want, want_len) == 0 && (p[want_len] == '\r' || p[want_len] == '\n')) {
                    found = 1;
                    break;
                }
                p = strchr(p, '\n');
                if (p != NULL) { p++; }
            }
            if (found) { break; }
        } else {
            usleep(10000);
        }
    }
    close(fd);
    return n;
}

static void finish(void)
{
    unsigned char buf[4096];
    size_t n = take_pending(buf, sizeof(buf));
    add_escaped("unread", buf, n);
    printf("%s\n", line);
    fflush(stdout);
}

/* Wait until the drive shows the data file again (after a commit or an erase). */
static int wait_drive(void)
{
    struct stat st;
    long long end = now_ms() + DRIVE_WAIT_MS;
    while (now_ms() < end) {
        if (stat(data_file, &st) == 0) { return 1; }
        usleep(20000);
    }
    return 0;
}

/* OmApi reads the port with read(); make a read with nothing to read return after 0.1 s rather
   than block, so that OmApi's own per-command timeouts apply (OmApi sets only the flags). */
static int prepare_port(void)
{
    struct termios t;
    int fd = open(port_path, O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (fd < 0) { return -1; }
    if (tcgetattr(fd, &t) != 0) { close(fd); return -1; }
    cfmakeraw(&t);
    t.c_cc[VMIN] = 0;
    t.c_cc[VTIME] = 1;
    int rc = tcsetattr(fd, TCSANOW, &t);
    close(fd);
    return rc;
}

/* ------------------------------------------------------------------ clock (OMGui's SyncTime) */

static OM_DATETIME pack_tm(const struct tm *tm)
{
    return OM_DATETIME_FROM_YMDHMS(tm->tm_year + 1900, tm->tm_mon + 1, tm->tm_mday, tm->tm_hour,
                                   tm->tm_min, tm->tm_sec);
}

static long long seconds_of(OM_DATETIME t)
{
    struct tm tm = {0};
    tm.tm_year = (int)OM_DATETIME_YEAR(t) - 1900;
    tm.tm_mon = OM_DATETIME_MONTH(t) - 1;
    tm.tm_mday = OM_DATETIME_DAY(t);
    tm.tm_hour = OM_DATETIME_HOURS(t);
    tm.tm_min = OM_DATETIME_MINUTES(t);
    tm.tm_sec = OM_DATETIME_SECONDS(t);
    return (long long)timegm(&tm);
}

static OM_DATETIME local_after(time_t t, long seconds)
{
    struct tm tm;
    time_t later = t + seconds;
    localtime_r(&later, &tm);
    return pack_tm(&tm);
}

/* ------------------------------------------------------------------ phases */

static void read_phase(int id)
{
    int rc, a, b, c;
    unsigned int session;
    OM_DATETIME t, t2;
    char text[OM_METADATA_SIZE + 1];

    { int ids[4] = {0}; rc = OmGetDeviceIds(ids, 4); begin("read", "OmGetDeviceIds", rc);
      add(" count=%d first=%d", rc, ids[0]); finish(); }
    { char buf[OM_MAX_PATH]; rc = OmGetDeviceSerial(id, buf); begin("read", "OmGetDeviceSerial", rc);
      add_string("serial", rc == OM_OK ? buf : ""); finish(); }
    { char buf[OM_MAX_PATH]; rc = OmGetDevicePort(id, buf); begin("read", "OmGetDevicePort", rc);
      add_string("port", rc == OM_OK ? buf : ""); finish(); }
    { char buf[OM_MAX_PATH]; rc = OmGetDevicePath(id, buf); begin("read", "OmGetDevicePath", rc);
      add_string("path", rc == OM_OK ? buf : ""); finish(); }

    a = b = -1;
    rc = OmGetVersion(id, &a, &b); begin("read", "OmGetVersion", rc);
    add(" firmware=%d hardware=%d", a, b); finish();
    rc = OmGetBatteryLevel(id); begin("read", "OmGetBatteryLevel", rc); add(" value=%d", rc); finish();
    rc = OmGetBatteryHealth(id); begin("read", "OmGetBatteryHealth", rc); add(" value=%d", rc); finish();
    rc = OmGetMemoryHealth(id); begin("read", "OmGetMemoryHealth", rc); add(" value=%d", rc); finish();
    a = -1;
    rc = OmIsLocked(id, &a); begin("read", "OmIsLocked", rc); add(" locked=%d has_code=%d", rc, a); finish();
    t = 0;
    rc = OmGetLastConfigTime(id, &t); begin("read", "OmGetLastConfigTime", rc); add_time("time", t); finish();
    rc = OmGetEcc(id); begin("read", "OmGetEcc", rc); add(" value=%d", rc); finish();
    t = 0;
    rc = OmGetTime(id, &t); begin("read", "OmGetTime", rc); add_time("time", t); finish();
    t = t2 = 0;
    rc = OmGetDelays(id, &t, &t2); begin("read", "OmGetDelays", rc);
    add_time("start", t); add_time("stop", t2); finish();
    session = 0;
    rc = OmGetSessionId(id, &session); begin("read", "OmGetSessionId", rc); add(" session=%u", session);
    finish();
    rc = OmSelfTest(id); begin("read", "OmSelfTest", rc); add(" value=%d", rc); finish();
    a = -1;
    rc = OmGetMaxSamples(id, &a); begin("read", "OmGetMaxSamples", rc); add(" value=%d", a); finish();
    text[0] = '\0';
    rc = OmGetMetadata(id, text); begin("read", "OmGetMetadata", rc); add_string("metadata", text); finish();
    a = b = 0;
    rc = OmGetAccelConfig(id, &a, &b); begin("read", "OmGetAccelConfig", rc);
    add(" rate=%d range=%d gyro=%d", a, b & 0xffff, b >> 16); finish();
    a = b = c = 0;
    rc = OmGetAccelerometer(id, &a, &b, &c); begin("read", "OmGetAccelerometer", rc);
    add(" x=%d y=%d z=%d", a, b, c); finish();
    rc = OmSetLed(id, OM_LED_MAGENTA); begin("read", "OmSetLed", rc); add(" led=%d", OM_LED_MAGENTA);
    finish();
    rc = OmSetLed(id, OM_LED_AUTO); begin("read", "OmSetLed(auto)", rc); add(" led=%d", OM_LED_AUTO);
    finish();
    rc = OmGetDataFileSize(id); begin("read", "OmGetDataFileSize", rc); add(" size=%d", rc); finish();
    { int bs = 0, off = 0, nb = 0; t = t2 = 0;
      rc = OmGetDataRange(id, &bs, &off, &nb, &t, &t2); begin("read", "OmGetDataRange", rc);
      add(" block=%d offset=%d blocks=%d", bs, off, nb); add_time("first", t); add_time("last", t2);
      finish(); }
}

static void download_phase(int id, const char *destination)
{
    OM_DOWNLOAD_STATUS status = OM_DOWNLOAD_NONE;
    int value = -1, rc;
    long long end;

    rc = OmBeginDownloading(id, 0, -1, destination);
    begin("download", "OmBeginDownloading", rc); finish();
    /* the download thread sets OM_DOWNLOAD_PROGRESS itself, so a wait made before it has started
       returns at once: wait until the download has ended, as OMGui's callback does */
    end = now_ms() + DOWNLOAD_WAIT_MS;
    do {
        rc = OmWaitForDownload(id, &status, &value);
        if (OM_FAILED(rc) || status == OM_DOWNLOAD_COMPLETE || status == OM_DOWNLOAD_ERROR
                || status == OM_DOWNLOAD_CANCELLED) { break; }
        usleep(10000);
    } while (now_ms() < end);
    begin("download", "OmWaitForDownload", rc); add(" status=%d value=%d", (int)status, value); finish();
}

/* The header fields that decide what a device records, read from the data file's first bytes at
   the offsets of the CWA header (openmovement Docs/ax3/cwa.h). OmApi's OM_READER_HEADER_PACKET
   cannot be used for this: it declares the times as OM_DATETIME, an unsigned long, which is 8 bytes
   on 64-bit Linux, so every field after byte 13 is misplaced there. */
static unsigned int le32(const unsigned char *b)
{
    return b[0] | b[1] << 8 | b[2] << 16 | (unsigned int)b[3] << 24;
}

static void header_fields(const char *phase)
{
    unsigned char h[64];
    size_t n = 0;
    FILE *f = fopen(data_file, "rb");
    if (f != NULL) { n = fread(h, 1, sizeof(h), f); fclose(f); }
    begin(phase, "header", n == sizeof(h) ? OM_OK : OM_E_ACCESS_DENIED);
    if (n == sizeof(h)) {
        add(" session=%u start_raw=0x%08x stop_raw=0x%08x capacity=%u rate_code=%u debug=%u",
            le32(h + 7), le32(h + 13), le32(h + 17), le32(h + 21), h[36], h[26]);
        add_time("start", le32(h + 13));
        add_time("stop", le32(h + 17));
    }
    finish();
}

static void file_readback(const char *phase, int id)
{
    int rc, size, bs = 0, off = 0, nb = 0, device = -1;
    unsigned int session = 0;
    OM_DATETIME t = 0, t2 = 0;
    OmReaderHandle reader;

    size = OmGetDataFileSize(id);
    begin(phase, "OmGetDataFileSize", size); add(" size=%d", size); finish();
    rc = OmGetDataRange(id, &bs, &off, &nb, &t, &t2);
    begin(phase, "OmGetDataRange", rc); add(" block=%d offset=%d blocks=%d", bs, off, nb); finish();
    reader = OmReaderOpen(data_file);
    begin(phase, "OmReaderOpen", reader == NULL ? OM_E_ACCESS_DENIED : OM_OK); finish();
    if (reader != NULL) {
        const char *meta = OmReaderMetadata(reader, &device, &session);
        char trimmed[OM_METADATA_SIZE + 1];
        size_t n = 0;
        if (meta != NULL) {
            snprintf(trimmed, sizeof(trimmed), "%s", meta);
            n = strlen(trimmed);
            while (n > 0 && trimmed[n - 1] == ' ') { trimmed[--n] = '\0'; }
        }
        begin(phase, "OmReaderMetadata", meta == NULL ? OM_E_FAIL : OM_OK);
        add(" device=%d session=%u", device, session);
        add_escaped("metadata", (const unsigned char *)(meta == NULL ? "" : trimmed), n);
        finish();
        OmReaderClose(reader);
    }
    header_fields(phase);
}

static void erase_or_commit(const char *phase, const char *call, int id, OM_ERASE_LEVEL level)
{
    unsigned char late[256];
    size_t n = 0;
    int rc = OmEraseDataAndCommit(id, level);
    begin(phase, call, rc);
    if (!OM_FAILED(rc) && level == OM_ERASE_NONE) {
        /* OmApi returned at "COMMIT: Delayed activation."; the firmware prints "COMMIT" when done */
        n = take_line("COMMIT", late, sizeof(late), DRIVE_WAIT_MS);
        add_escaped("late", late, n);
    }
    add(" drive=%d", wait_drive());
    finish();
}

static void clear_phase(int id)
{
    int rc, a = 0, b = 0;
    unsigned int session = 12345;
    OM_DATETIME t = 0, t2 = 0;
    char text[OM_METADATA_SIZE + 1];

    rc = OmSetSessionId(id, 0); begin("clear", "OmSetSessionId", rc); add(" session=0"); finish();
    rc = OmSetMetadata(id, "", 0); begin("clear", "OmSetMetadata", rc); add_string("metadata", ""); finish();
    rc = OmSetDelays(id, OM_DATETIME_INFINITE, OM_DATETIME_INFINITE); begin("clear", "OmSetDelays", rc);
    add_time("start", OM_DATETIME_INFINITE); add_time("stop", OM_DATETIME_INFINITE); finish();
    rc = OmSetAccelConfig(id, OM_ACCEL_DEFAULT_RATE, OM_ACCEL_DEFAULT_RANGE);
    begin("clear", "OmSetAccelConfig", rc);
    add(" rate=%d range=%d", OM_ACCEL_DEFAULT_RATE, OM_ACCEL_DEFAULT_RANGE); finish();
    erase_or_commit("clear", "OmEraseDataAndCommit(QUICKFORMAT)", id, OM_ERASE_QUICKFORMAT);

    /* read back: the settings through OmApi, then what the data file holds */
    rc = OmGetSessionId(id, &session); begin("cleared", "OmGetSessionId", rc); add(" session=%u", session);
    finish();
    rc = OmGetDelays(id, &t, &t2); begin("cleared", "OmGetDelays", rc); add_time("start", t);
    add_time("stop", t2); finish();
    rc = OmGetAccelConfig(id, &a, &b); begin("cleared", "OmGetAccelConfig", rc);
    add(" rate=%d range=%d gyro=%d", a, b & 0xffff, b >> 16); finish();
    text[0] = '\0';
    rc = OmGetMetadata(id, text); begin("cleared", "OmGetMetadata", rc); add_string("metadata", text);
    finish();
    file_readback("cleared", id);
}

static void sync_time(int id)
{
    /* OmDevice.SyncTime: at a second boundary set the PC's local time, read it back after 1.2 s
       (within 5 s), then see the clock tick (within 4 s) */
    struct timeval tv;
    struct tm tm;
    time_t second;
    OM_DATETIME set, got = 0, later = 0;
    int rc;
    long long end;

    gettimeofday(&tv, NULL);
    second = tv.tv_sec;
    do { gettimeofday(&tv, NULL); } while (tv.tv_sec == second);
    localtime_r(&tv.tv_sec, &tm);
    set = pack_tm(&tm);
    rc = OmSetTime(id, set); begin("record", "OmSetTime", rc); add_time("time", set); finish();
    usleep(1200000);
    rc = OmGetTime(id, &got); begin("record", "OmGetTime", rc); add_time("time", got);
    add(" delta_s=%lld", seconds_of(got) - seconds_of(set)); finish();
    end = now_ms() + 4000;
    do {
        rc = OmGetTime(id, &later);
        if (OM_FAILED(rc) || later > got) { break; }
    } while (now_ms() < end);
    begin("record", "OmGetTime(tick)", rc); add_time("time", later); add(" ticked=%d", later > got); finish();
}

static void record_phase(int id, unsigned int session, const char *metadata, int rate, int range,
                         int gyro, int debug)
{
    int rc, a = -1, b = 0;
    unsigned int got_session = 0;
    OM_DATETIME start, stop, t = 0, t2 = 0;
    char text[OM_METADATA_SIZE + 1];
    char response[256], *parts[4] = {0};
    char command[32];
    time_t now = time(NULL);

    rc = OmSetSessionId(id, session); begin("record", "OmSetSessionId", rc); add(" session=%u", session);
    finish();
    rc = OmSetMetadata(id, metadata, (int)strlen(metadata)); begin("record", "OmSetMetadata", rc);
    add_string("metadata", metadata); finish();
    rc = OmSetMaxSamples(id, 0); begin("record", "OmSetMaxSamples", rc); add(" value=0"); finish();
    rc = OmSetAccelConfig(id, rate, range | (gyro > 0 ? gyro << 16 : 0));
    begin("record", "OmSetAccelConfig", rc); add(" rate=%d range=%d gyro=%d", rate, range, gyro); finish();
    sync_time(id);
    /* OmDevice.SetDebug: OmCommand("DEBUG n", expected "DEBUG=") */
    snprintf(command, sizeof(command), "\r\nDEBUG %d\r\n", debug);
    rc = OmCommand(id, command, response, sizeof(response), "DEBUG=", 2000, parts, 4);
    begin("record", "OmCommand(DEBUG)", rc); add(" value=%d", parts[1] != NULL ? atoi(parts[1]) : -1);
    finish();
    start = local_after(now, 3600);
    stop = local_after(now, 2 * 86400);
    rc = OmSetDelays(id, start, stop); begin("record", "OmSetDelays", rc);
    add_time("start", start); add_time("stop", stop); finish();
    erase_or_commit("record", "OmCommit", id, OM_ERASE_NONE);

    /* read back every setting through OmApi, then from the data file's header */
    rc = OmGetSessionId(id, &got_session); begin("recorded", "OmGetSessionId", rc);
    add(" session=%u", got_session); finish();
    text[0] = '\0';
    rc = OmGetMetadata(id, text); begin("recorded", "OmGetMetadata", rc); add_string("metadata", text);
    finish();
    rc = OmGetMaxSamples(id, &a); begin("recorded", "OmGetMaxSamples", rc); add(" value=%d", a); finish();
    a = 0;
    rc = OmGetAccelConfig(id, &a, &b); begin("recorded", "OmGetAccelConfig", rc);
    add(" rate=%d range=%d gyro=%d", a, b & 0xffff, b >> 16); finish();
    rc = OmGetDelays(id, &t, &t2); begin("recorded", "OmGetDelays", rc); add_time("start", t);
    add_time("stop", t2); finish();
    rc = OmCommand(id, "\r\nDEBUG\r\n", response, sizeof(response), "DEBUG=", 2000, parts, 4);
    begin("recorded", "OmCommand(DEBUG)", rc); add(" value=%d", parts[1] != NULL ? atoi(parts[1]) : -1);
    finish();
    t = 0;
    rc = OmGetLastConfigTime(id, &t); begin("recorded", "OmGetLastConfigTime", rc); add_time("time", t);
    finish();
    file_readback("recorded", id);
}

int main(int argc, char *argv[])
{
    int id, rc;

    if (argc != 11) {
        fprintf(stderr, "usage: harness SERIAL PORT VOLUME DOWNLOAD SESSION METADATA RATE RANGE GYRO "
                        "DEBUG\n");
        return 2;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);
    port_path = argv[2];
    volume_path = argv[3];
    snprintf(data_file, sizeof(data_file), "%s/CWA-DATA.CWA", volume_path);
    if (finder_set_device(argv[1], port_path, volume_path) != 0) {
        fprintf(stderr, "harness: a path or serial is too long\n");
        return 2;
    }
    if (prepare_port() != 0) {
        fprintf(stderr, "harness: cannot open the port %s: %s\n", port_path, strerror(errno));
        return 2;
    }
    id = (int)finder_id_from_serial(argv[1]);

    rc = OmStartup(OM_VERSION); begin("start", "OmStartup", rc); finish();
    if (OM_FAILED(rc)) { return 2; }
    read_phase(id);
    download_phase(id, argv[4]);
    clear_phase(id);
    record_phase(id, (unsigned int)strtoul(argv[5], NULL, 10), argv[6], atoi(argv[7]), atoi(argv[8]),
                 atoi(argv[9]), atoi(argv[10]));
    rc = OmShutdown(); begin("end", "OmShutdown", rc); finish();
    return 0;
}
