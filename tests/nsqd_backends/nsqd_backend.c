/*
 * nsqd_backend.c - a backend (the drone's side) of the Nsqd drone protocol over TCP.
 *
 * Written for mcp-conform's tests: correct by default, with exactly one deliberate fault
 * planted at run time by `--fault NAME` (`--list-faults` prints the names; the rule each one
 * breaks is in build.py's FAULTS).  Every fault is marked "FAULT name" in the code below.
 *
 * Wire format: big-endian; a frame is int32 L (counting its own 4 bytes, the id byte and the
 * body, 5 <= L <= 8192), a message id byte, then the body.  Field types: bool (1 byte),
 * int32, "float" (the value truncated to an integer, sent as uint32), string (int16 length n,
 * then n bytes).  The backend serves one client at a time, sends UPDATE every
 * --update-period seconds while one is connected, and answers a frame it cannot use with an
 * ERROR frame naming it.  A framing error (bad L) closes the connection.
 *
 * Usage: nsqd_backend [--host H] [--port P] [--update-period S] [--fault NAME]
 * Build: see build.py (gcc -std=c99 ... -fsanitize=address,undefined).
 */
#include <ctype.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netdb.h>
#include <poll.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>
#include <unistd.h>

#define MAX_FRAME 8192          /* largest valid L */
#define IN_CAP (2 * MAX_FRAME)  /* holds any partial frame plus one more read */
#define OUT_CAP 65536           /* queued frames for a client that reads slowly */

/* ---- faults ----------------------------------------------------------------------------- */

enum fault {
    F_NONE, F_LEN_EXCLUDES_SELF, F_NO_REASSEMBLY, F_FIRST_FRAME_PER_READ, F_NO_CLOSE_BAD_LEN,
    F_SMALL_FRAME_LIMIT, F_UPDATE_STOPS, F_STATE_LITTLE_ENDIAN, F_WRONG_STOP_TEST_STATE,
    F_UNKNOWN_ID_NO_SKIP, F_UNKNOWN_ID_HOVERS, F_CRASH_NEGATIVE_STRING, F_CRASH_BAD_NUMBER,
    F_GPX_STACK_OVERFLOW, F_FD_LEAK, F_SECOND_CLIENT_KICKS_FIRST, F_STALE_PARTIAL_FRAME,
    F_NO_ERROR_ON_UNKNOWN_ID, F_OVERREAD_EVERY_FRAME, F_EARLY_RETURN_KEEPS_SIZE,
    F_SWITCH_FALLTHROUGH, F_UNBOUNDED_GPX_ALLOC, F_COUNT
};

static const char *const FAULT_NAMES[F_COUNT] = {
    "none", "length-excludes-self", "no-reassembly", "first-frame-per-read",
    "no-close-on-bad-length", "small-frame-limit", "update-stops", "update-state-little-endian",
    "wrong-stop-test-state", "unknown-id-no-skip", "unknown-id-hovers",
    "crash-on-negative-string", "crash-on-bad-number", "gpx-stack-overflow", "fd-leak",
    "second-client-kicks-first", "stale-partial-frame", "no-error-on-unknown-id",
    "overread-every-frame", "early-return-keeps-size", "switch-fallthrough",
    "unbounded-gpx-alloc",
};

static enum fault fault = F_NONE;
#define FAULT(f) (fault == (f))

/* ---- messages and states -------------------------------------------------------------- */

enum {
    MSG_ERROR = 0, MSG_UPDATE = 1, MSG_TAKEOFF = 4, MSG_LAND = 5, MSG_SET_RPYTFF = 7,
    MSG_STOP_TEST = 8, MSG_SET_HOVERHEIGHT = 9, MSG_STOP_HOVER_TEST = 10,
    MSG_UPLOAD_FLIGHTPATH = 12, MSG_CAPTURE_IMAGES = 13, MSG_STOP_CAPTURE_IMAGES = 14,
    MSG_LAST = 14
};

enum state {
    GROUNDED = 0, ARMED = 1, HOVER = 2, INITIALISE_ENROUTE = 3, ENROUTE = 4, ENROUTE_TURN = 5,
    ENROUTE_STOPPED = 6, PUBLISH_ANGLE = 7, START_TEST = 8, RUNNING_TEST = 9, STOP_TEST = 10,
    START_HOVER_TEST = 11, HOVER_LOGGING = 12, STOP_HOVER_LOGGING = 13, CAPTURE_IMAGES = 14
};

/*
 * Body layouts, one character per field, in order:
 *   b bool (1 byte)   f "float" (4 bytes)   i int32   p int32 flag within 0..2
 *   s string          n string holding a finite decimal number   g string holding a GPX document
 */
struct layout {
    const char *name;
    const char *fields;
};

static const struct layout LAYOUTS[MSG_LAST + 1] = {
    {"ERROR", "s"}, {"UPDATE", "fffffffi"}, {"SET_AUTH", ""}, {"ARM", "b"}, {"TAKEOFF", ""},
    {"LAND", ""}, {"SET_PID", "nnnp"}, {"SET_RPYTFF", "nnnnis"}, {"STOP_TEST", ""},
    {"SET_HOVERHEIGHT", "fs"}, {"STOP_HOVER_TEST", ""}, {"FOLLOW_LINE", ""},
    {"UPLOAD_FLIGHTPATH", "g"}, {"CAPTURE_IMAGES", ""}, {"STOP_CAPTURE_IMAGES", ""},
};

static const char FLAG_OUTSIDE[] = "flag outside 0..2";  /* check_body's answer to a bad flag */

/* ---- process-wide state ---------------------------------------------------------------- */

static int state = GROUNDED;        /* the flight state; kept across connections */
static double update_period = 0.4;

static int cfd = -1;                /* the connected client, or -1 */
static uint8_t *in_buf;             /* received bytes not yet consumed (heap: IN_CAP) */
static size_t in_len;
static size_t kept_size;            /* 0, or the size the next frame is read with (a fault's) */
static uint8_t out_buf[OUT_CAP];    /* frames not yet sent */
static size_t out_len;
static double accepted_at, next_update;

static int sig_pipe[2] = {-1, -1};  /* SIGTERM/SIGINT wake poll() through this pipe */

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec / 1e9;
}

static int32_t get_i32(const uint8_t *p)
{
    return (int32_t)(((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3]);
}

static int16_t get_i16(const uint8_t *p)
{
    return (int16_t)(uint16_t)((p[0] << 8) | p[1]);
}

static void *xmalloc(size_t n)
{
    void *p = malloc(n);
    if (!p) {
        perror("malloc");
        exit(1);
    }
    return p;
}

static void put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)(v >> 24);
    p[1] = (uint8_t)(v >> 16);
    p[2] = (uint8_t)(v >> 8);
    p[3] = (uint8_t)v;
}

/* ---- sending ---------------------------------------------------------------------------- */

/* Queue one frame; a client that does not read loses whole frames, never part of one. */
static void queue_frame(uint8_t id, const uint8_t *body, size_t len)
{
    if (out_len + 5 + len > OUT_CAP)
        return;
    /* FAULT length-excludes-self: L leaves out the 4 bytes of the length itself */
    uint32_t L = (uint32_t)(FAULT(F_LEN_EXCLUDES_SELF) ? 1 + len : 5 + len);
    put_u32(out_buf + out_len, L);
    out_buf[out_len + 4] = id;
    memcpy(out_buf + out_len + 5, body, len);
    out_len += 5 + len;
}

static void queue_error(const char *text)
{
    uint8_t body[2 + 256];
    size_t n = strlen(text);
    if (n > 256)
        n = 256;
    body[0] = (uint8_t)(n >> 8);
    body[1] = (uint8_t)n;
    memcpy(body + 2, text, n);
    queue_frame(MSG_ERROR, body, 2 + n);
}

static void queue_update(void)
{
    uint8_t body[32] = {0};  /* roll, pitch, yaw, thrust, lat, lon: 0 */
    put_u32(body + 24, state == GROUNDED ? 0 : 10);  /* alt */
    uint32_t s = (uint32_t)state;
    if (FAULT(F_STATE_LITTLE_ENDIAN))  /* FAULT update-state-little-endian: bytes reversed */
        s = (s >> 24) | ((s >> 8) & 0xff00u) | ((s << 8) & 0xff0000u) | (s << 24);
    put_u32(body + 28, s);
    queue_frame(MSG_UPDATE, body, sizeof body);
}

/* Send what the socket takes now; -1 when the connection is gone. */
static int flush_output(void)
{
    while (out_len > 0) {
        ssize_t n = send(cfd, out_buf, out_len, MSG_NOSIGNAL);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            return (errno == EAGAIN || errno == EWOULDBLOCK) ? 0 : -1;
        }
        memmove(out_buf, out_buf + n, out_len - (size_t)n);
        out_len -= (size_t)n;
    }
    return 0;
}

/* ---- body checks ------------------------------------------------------------------------ */

/* The n bytes at s are a finite decimal number (strtod consumes all of them). */
static int parse_number(const char *s, size_t n, double *out)
{
    char *end;
    double v = strtod(s, &end);
    if (end == s || end != s + n || !isfinite(v))
        return 0;
    *out = v;
    return 1;
}

/* The tag [tag, end) has an attribute NAME="number" (or '...') with |number| <= lim. */
static int attr_in_range(const char *tag, const char *end, const char *name, double lim)
{
    size_t k = strlen(name);
    for (const char *p = tag + 1; p + k + 2 < end; p++) {
        if (!isspace((unsigned char)p[-1]) || strncmp(p, name, k) != 0 || p[k] != '=')
            continue;
        char quote = p[k + 1];
        if (quote != '"' && quote != '\'')
            continue;
        const char *v = p + k + 2;
        const char *close = memchr(v, quote, (size_t)(end - v));
        char num[48];
        double x;
        if (!close || (size_t)(close - v) >= sizeof num)
            return 0;
        memcpy(num, v, (size_t)(close - v));
        num[close - v] = '\0';
        return parse_number(num, (size_t)(close - v), &x) && fabs(x) <= lim;
    }
    return 0;
}

/* A GPX document: "<gpx" and one tag with lat="..." within +-90 and lon="..." within +-180. */
static int gpx_scan(const char *doc)
{
    if (!strstr(doc, "<gpx"))
        return 0;
    for (const char *t = strchr(doc, '<'); t; t = strchr(t + 1, '<')) {
        const char *end = strchr(t, '>');
        if (!end)
            end = t + strlen(t);
        if (attr_in_range(t, end, "lat", 90.0) && attr_in_range(t, end, "lon", 180.0))
            return 1;
    }
    return 0;
}

/*
 * FAULT unbounded-gpx-alloc: a parser of the route's <rte> nesting keeps one heap node per
 * open <rte>.  At 200 levels its "grow the stack" loop never ends (the bound it tests is
 * never raised): it allocates and fills 1 MiB per turn, never freed, then spins without
 * serving.  Only the cap on the allocations (256 MiB, to spare the test machine) is not
 * part of the bug.  Fewer than 200 levels are parsed and freed correctly.
 */
#define RTE_LEVELS 200
static void *rte_leak;  /* the spin's blocks, chained (reachable: no leak report) */

static void rte_stack_full(size_t depth)
{
    size_t cap = RTE_LEVELS, total = 0;
    const size_t block = (size_t)1 << 20;
    while (depth >= cap) {  /* the bug: nothing in the loop raises cap */
        if (total < ((size_t)256 << 20)) {
            void **b = xmalloc(block);
            memset(b, 0x5a, block);
            *b = rte_leak;
            rte_leak = b;
            total += block;
        } else {
            struct timespec nap = {0, 1000000};  /* spin, but let the 2 cores breathe */
            nanosleep(&nap, NULL);
        }
    }
}

static void gpx_rte_nesting(const char *doc)
{
    char *level[RTE_LEVELS];
    size_t depth = 0;
    for (const char *t = strchr(doc, '<'); t; t = strchr(t + 1, '<')) {
        if (!strncmp(t, "</rte>", 6) && depth > 0) {
            free(level[--depth]);
        } else if (!strncmp(t, "<rte>", 5)) {
            level[depth++] = xmalloc(64);
            if (depth == RTE_LEVELS)
                rte_stack_full(depth);
        }
    }
    while (depth > 0)
        free(level[--depth]);
}

static int gpx_ok(const char *text, size_t n)
{
    if (FAULT(F_UNBOUNDED_GPX_ALLOC))
        gpx_rte_nesting(text);
    if (FAULT(F_GPX_STACK_OVERFLOW)) {  /* FAULT gpx-stack-overflow: no bound on the copy */
        char doc[256];
        memcpy(doc, text, n + 1);
        return gpx_scan(doc);
    }
    return gpx_scan(text);
}

/* A NUL-terminated heap copy of a string field's n bytes. */
static char *copy_text(const uint8_t *p, int16_t n)
{
    /* 16-bit sizes as the field has; n >= 0 here unless FAULT crash-on-negative-string, where
     * n = -1 makes len 65535 and the buffer malloc(0): memcpy runs far past both buffers. */
    uint16_t len = (uint16_t)n;
    char *text = xmalloc((uint16_t)(len + 1));
    memcpy(text, p, len);
    text[len] = '\0';
    return text;
}

/* Check one string field of KIND (s, n or g) with length n and rest bytes after its length. */
static const char *check_string(char kind, int16_t n, const uint8_t *p, size_t rest)
{
    if ((n < 0 && !FAULT(F_CRASH_NEGATIVE_STRING)) || (n > 0 && (size_t)n > rest))
        return "string length out of range";
    char *text = copy_text(p, n);
    const char *why = NULL;
    double x;
    if (kind == 'n' && !parse_number(text, (size_t)n, &x)) {
        if (FAULT(F_CRASH_BAD_NUMBER)) {  /* FAULT crash-on-bad-number: like std::stof's throw */
            fprintf(stderr, "terminate called after throwing an instance of "
                            "'std::invalid_argument'\n  what():  stof\n");
            abort();
        }
        why = "text is not a finite decimal number";
    } else if (kind == 'g' && !gpx_ok(text, (size_t)n)) {
        why = "text is not a GPX document";
    }
    free(text);
    return why;
}

/* NULL when the body fits the layout, else what is wrong with it.  Extra bytes are ignored. */
static const char *check_body(const char *fields, const uint8_t *p, size_t len)
{
    const uint8_t *end = p + len;
    for (const char *f = fields; *f; f++) {
        size_t rest = (size_t)(end - p);
        if (*f == 'b') {
            if (rest < 1)
                return "body too short";
            p += 1;
        } else if (*f == 'f' || *f == 'i' || *f == 'p') {
            if (rest < 4)
                return "body too short";
            if (*f == 'p' && (get_i32(p) < 0 || get_i32(p) > 2))
                return FLAG_OUTSIDE;
            p += 4;
        } else {  /* a string: s, n or g */
            if (rest < 2)
                return "body too short";
            int16_t n = get_i16(p);
            const char *why = check_string(*f, n, p + 2, rest - 2);
            if (why)
                return why;
            p += 2 + n;
        }
    }
    return NULL;
}

/* ---- receiving -------------------------------------------------------------------------- */

/* Handle one frame's id and body: 1 when done with it, 0 when it returned early (a fault's). */
static int handle_frame(uint8_t id, const uint8_t *body, size_t len)
{
    char text[160];
    if (id > MSG_LAST) {
        if (!FAULT(F_NO_ERROR_ON_UNKNOWN_ID)) {  /* FAULT no-error-on-unknown-id */
            snprintf(text, sizeof text, "unknown message id %u", (unsigned)id);
            queue_error(text);
        }
        if (FAULT(F_UNKNOWN_ID_HOVERS))  /* FAULT unknown-id-hovers */
            state = HOVER;
        return 1;
    }
    const struct layout *m = &LAYOUTS[id];
    const char *why = id == MSG_ERROR ? NULL : check_body(m->fields, body, len);
    if (why) {
        snprintf(text, sizeof text, "malformed %s (id %u): %s", m->name, (unsigned)id, why);
        queue_error(text);
        /* FAULT early-return-keeps-size: like Nsqd's E-6, SET_PID's flag check returns before
         * the frame size is reset, so the next frame is read with this frame's size */
        return !(FAULT(F_EARLY_RETURN_KEEPS_SIZE) && why == FLAG_OUTSIDE);
    }
    switch (id) {  /* the command's effect on the flight state; the others leave it */
    case MSG_TAKEOFF:           state = HOVER; break;
    case MSG_LAND:              state = GROUNDED; break;
    case MSG_SET_RPYTFF:        state = START_TEST; break;
    case MSG_STOP_TEST:  /* FAULT wrong-stop-test-state */
        state = FAULT(F_WRONG_STOP_TEST_STATE) ? GROUNDED : STOP_TEST;
        break;
    case MSG_SET_HOVERHEIGHT:   state = START_HOVER_TEST; break;
    case MSG_STOP_HOVER_TEST:   state = STOP_HOVER_LOGGING; break;
    case MSG_UPLOAD_FLIGHTPATH: state = INITIALISE_ENROUTE; break;
    case MSG_CAPTURE_IMAGES:
        state = CAPTURE_IMAGES;
        if (!FAULT(F_SWITCH_FALLTHROUGH))  /* FAULT switch-fallthrough: the break is missing */
            break;
        /* fall through */
    case MSG_STOP_CAPTURE_IMAGES: state = HOVER; break;
    default: break;  /* ERROR (the client's complaint), SET_AUTH, ARM, SET_PID, FOLLOW_LINE */
    }
    return 1;
}

/*
 * FAULT overread-every-frame: Nsqd's HandleConnection copies the frame into a buffer of
 * exactly its size and reads it through `Decoder decoder(b.data() + 4, _currentSize)`: a
 * decoder that starts after the length prefix but takes the whole frame's size.  This
 * decoder reads the id in place and copies its whole window before it decodes a body, so
 * every frame with body fields reads 4 bytes past the buffer.
 */
static int handle_via_decoder(const uint8_t *frame, size_t size)
{
    uint8_t *b = xmalloc(size), *window = NULL;
    memcpy(b, frame, size);
    uint8_t id = b[4];
    const uint8_t *body = b + 5;
    if (id > MSG_ERROR && id <= MSG_LAST && LAYOUTS[id].fields[0] != '\0') {
        window = xmalloc(size);
        memcpy(window, b + 4, size);  /* b[size .. size + 3] are past b's end */
        body = window + 1;
    }
    int done = handle_frame(id, body, size - 5);
    free(window);
    free(b);
    return done;
}

/* Consume the whole frames in in_buf (one read's worth added); -1 on a framing error. */
static int process_input(void)
{
    /* FAULT small-frame-limit */
    const int32_t max_len = FAULT(F_SMALL_FRAME_LIMIT) ? 4096 : MAX_FRAME;
    size_t off = 0;
    int frames = 0;
    while (in_len - off >= 4) {
        /* the frame's own length, but after FAULT early-return-keeps-size */
        int32_t L = kept_size ? (int32_t)kept_size : get_i32(in_buf + off);
        if (L < 5 || L > max_len) {
            if (!FAULT(F_NO_CLOSE_BAD_LEN)) {
                in_len = 0;  /* nothing of a broken stream is kept, even by stale-partial-frame */
                return -1;
            }
            off += 4;  /* FAULT no-close-on-bad-length: skip the length, go on */
            continue;
        }
        if (in_len - off < (size_t)L)
            break;  /* the rest of this frame is still to come */
        uint8_t id = in_buf[off + 4];
        kept_size = 0;
        /* FAULT first-frame-per-read: the frames after this read's first are dropped */
        if (!(FAULT(F_FIRST_FRAME_PER_READ) && frames > 0)) {
            int done = FAULT(F_OVERREAD_EVERY_FRAME)
                           ? handle_via_decoder(in_buf + off, (size_t)L)
                           : handle_frame(id, in_buf + off + 5, (size_t)L - 5);
            if (!done)  /* FAULT early-return-keeps-size */
                kept_size = (size_t)L;
        }
        frames++;
        /* FAULT unknown-id-no-skip: an unknown id's body is left to be read as frames */
        off += (id > MSG_LAST && FAULT(F_UNKNOWN_ID_NO_SKIP)) ? 5 : (size_t)L;
    }
    memmove(in_buf, in_buf + off, in_len - off);
    in_len -= off;
    if (FAULT(F_NO_REASSEMBLY))  /* FAULT no-reassembly: a read's partial frame is dropped */
        in_len = 0;
    return 0;
}

static void drop_client(void)
{
    if (FAULT(F_FD_LEAK))  /* FAULT fd-leak: the peer sees the end, the fd stays open */
        shutdown(cfd, SHUT_RDWR);
    else
        close(cfd);
    cfd = -1;
    out_len = 0;
    kept_size = 0;
    if (!FAULT(F_STALE_PARTIAL_FRAME))  /* FAULT stale-partial-frame */
        in_len = 0;
}

static void read_client(void)
{
    size_t room = IN_CAP - in_len;
    if (room == 0) {  /* cannot happen: a partial frame is shorter than MAX_FRAME */
        drop_client();
        return;
    }
    ssize_t n = recv(cfd, in_buf + in_len, room, 0);
    if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR))
        return;
    if (n <= 0) {  /* FIN or RST: a partial frame goes with the connection */
        drop_client();
        return;
    }
    in_len += (size_t)n;
    if (process_input() < 0)
        drop_client();
}

static int set_nonblocking(int fd)
{
    int flags = fcntl(fd, F_GETFL);
    return flags < 0 ? -1 : fcntl(fd, F_SETFL, flags | O_NONBLOCK);
}

static void accept_client(int lfd)
{
    int fd = accept(lfd, NULL, NULL);
    if (fd < 0) {
        if (errno == EMFILE || errno == ENFILE) {
            perror("accept");
            poll(NULL, 0, 100);  /* the backlog stays readable: do not spin */
        }
        return;
    }
    if (cfd >= 0)  /* FAULT second-client-kicks-first (only then is a second one accepted) */
        drop_client();
    set_nonblocking(fd);
    cfd = fd;
    accepted_at = now();
    next_update = accepted_at;  /* the first UPDATE right away */
}

/* Queue the UPDATE that is due and schedule the next one. */
static void update_tick(double t)
{
    /* FAULT update-stops: silence after the connection's first 3 s */
    if (!(FAULT(F_UPDATE_STOPS) && t - accepted_at >= 3.0))
        queue_update();
    next_update += update_period;
    if (next_update <= t)
        next_update = t + update_period;
}

/* ---- setup ------------------------------------------------------------------------------ */

static void on_signal(int sig)
{
    int saved = errno;
    ssize_t w = write(sig_pipe[1], "x", 1);
    (void)sig;
    (void)w;
    errno = saved;
}

static int listen_on(const char *host, const char *port)
{
    struct addrinfo hints, *res, *ai;
    int fd = -1, one = 1;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    hints.ai_flags = AI_PASSIVE;
    int rc = getaddrinfo(host, port, &hints, &res);
    if (rc != 0) {
        fprintf(stderr, "nsqd_backend: %s: %s\n", host, gai_strerror(rc));
        return -1;
    }
    for (ai = res; ai; ai = ai->ai_next) {
        fd = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
        if (fd < 0)
            continue;
        setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
        if (bind(fd, ai->ai_addr, ai->ai_addrlen) == 0 && listen(fd, 16) == 0)
            break;
        close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    if (fd < 0)
        fprintf(stderr, "nsqd_backend: cannot listen on %s:%s: %s\n", host, port, strerror(errno));
    else
        set_nonblocking(fd);
    return fd;
}

static void usage(FILE *to)
{
    fprintf(to, "usage: nsqd_backend [--host H] [--port P] [--update-period S] [--fault NAME]"
                " [--list-faults]\n");
}

static int bad_usage(const char *what, const char *arg)
{
    fprintf(stderr, "nsqd_backend: %s: %s (try --help)\n", what, arg);
    return 2;
}

/* argv[*i] is NAME or NAME=VALUE: its value (advancing *i past it), or NULL if not NAME. */
static const char *option(int argc, char **argv, int *i, const char *name, int *missing)
{
    size_t k = strlen(name);
    if (strncmp(argv[*i], name, k) != 0)
        return NULL;
    if (argv[*i][k] == '=')
        return argv[*i] + k + 1;
    if (argv[*i][k] != '\0')
        return NULL;
    if (*i + 1 >= argc) {
        *missing = 1;
        return NULL;
    }
    return argv[++*i];
}

int main(int argc, char **argv)
{
    const char *host = "127.0.0.1", *port = "8888", *v;
    for (int i = 1; i < argc; i++) {
        int missing = 0;
        char *end;
        if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(argv[i], "--list-faults")) {
            for (int f = 1; f < F_COUNT; f++)
                puts(FAULT_NAMES[f]);
            return 0;
        } else if ((v = option(argc, argv, &i, "--host", &missing))) {
            host = v;
        } else if ((v = option(argc, argv, &i, "--port", &missing))) {
            long p = strtol(v, &end, 10);
            if (*v == '\0' || *end != '\0' || p < 1 || p > 65535)
                return bad_usage("--port wants 1..65535", v);
            port = v;
        } else if ((v = option(argc, argv, &i, "--update-period", &missing))) {
            update_period = strtod(v, &end);
            if (*v == '\0' || *end != '\0' || !isfinite(update_period) || update_period <= 0)
                return bad_usage("--update-period wants seconds > 0", v);
        } else if ((v = option(argc, argv, &i, "--fault", &missing))) {
            int f = F_COUNT;  /* "none" is accepted too: no fault */
            while (--f >= 0 && strcmp(v, FAULT_NAMES[f]) != 0)
                ;
            if (f < 0)
                return bad_usage("unknown fault (see --list-faults)", v);
            fault = (enum fault)f;
        } else {
            return bad_usage(missing ? "option needs a value" : "unknown option", argv[i]);
        }
    }

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = SIG_IGN;
    sigaction(SIGPIPE, &sa, NULL);
    if (pipe(sig_pipe) < 0 || set_nonblocking(sig_pipe[0]) < 0 || set_nonblocking(sig_pipe[1]) < 0) {
        perror("pipe");
        return 1;
    }
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGINT, &sa, NULL);

    int lfd = listen_on(host, port);
    if (lfd < 0)
        return 1;
    in_buf = xmalloc(IN_CAP);
    printf("listening on %s:%s\n", host, port);
    fflush(stdout);

    for (;;) {
        struct pollfd pf[3];
        int n = 0, i_lis = -1, i_cli = -1, timeout = -1;
        pf[n++] = (struct pollfd){sig_pipe[0], POLLIN, 0};
        if (cfd < 0 || FAULT(F_SECOND_CLIENT_KICKS_FIRST)) {
            i_lis = n;
            pf[n++] = (struct pollfd){lfd, POLLIN, 0};
        }
        if (cfd >= 0) {
            double wait = next_update - now();
            timeout = wait <= 0 ? 0 : (int)ceil(wait * 1000.0);
            i_cli = n;
            pf[n++] = (struct pollfd){cfd, (short)(POLLIN | (out_len ? POLLOUT : 0)), 0};
        }
        if (poll(pf, (nfds_t)n, timeout) < 0) {
            if (errno == EINTR)
                continue;
            perror("poll");
            break;
        }
        if (pf[0].revents)  /* SIGTERM or SIGINT */
            break;
        if (i_cli >= 0 && (pf[i_cli].revents & (POLLIN | POLLHUP | POLLERR)))
            read_client();
        if (cfd >= 0 && now() >= next_update)
            update_tick(now());
        if (cfd >= 0 && out_len > 0 && flush_output() < 0)
            drop_client();
        if (i_lis >= 0 && (pf[i_lis].revents & POLLIN))
            accept_client(lfd);
    }

    if (cfd >= 0)
        close(cfd);
    close(lfd);
    close(sig_pipe[0]);
    close(sig_pipe[1]);
    free(in_buf);
    return 0;
}
