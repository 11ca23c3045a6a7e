/*
 * replay_vectors: replays every test vector of spec/vectors through the C
 * API and checks each outcome, the digest and the final mirror state.
 *
 *   cc -std=c11 -I include psao-ffi/examples/c/replay_vectors.c \
 *      target/release/libpsao_ffi.a -lm -lpthread -ldl -o replay_vectors
 *   ./replay_vectors spec/vectors
 *
 * The vector format is spec/vectors/README.md's. The state listing is
 * rebuilt from the mirror through the API (instances, transforms, bucket
 * entries, point words and their fields) and compared token by token:
 * numbers as binary32 values (C and Rust print floats differently),
 * everything else as text. Exit status 0 when every vector passes.
 */
#define _POSIX_C_SOURCE 200809L
#include <dirent.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "psao.h"

/* A growable text buffer for the state listing. */
typedef struct {
    char *data;
    size_t len, cap;
} text;

static void text_printf(text *t, const char *fmt, ...) {
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        size_t room = t->cap - t->len;
        int n = vsnprintf(t->data ? t->data + t->len : NULL, room, fmt, ap);
        va_end(ap);
        if (n < 0) {
            fprintf(stderr, "vsnprintf failed\n");
            exit(2);
        }
        if ((size_t)n < room) {
            t->len += (size_t)n;
            return;
        }
        size_t cap = t->cap ? t->cap * 2 : 4096;
        while (cap - t->len <= (size_t)n) cap *= 2;
        char *p = realloc(t->data, cap);
        if (!p) {
            fprintf(stderr, "out of memory\n");
            exit(2);
        }
        t->data = p;
        t->cap = cap;
    }
}

static char *read_file(const char *path) {
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *buf = malloc((size_t)n + 1);
    if (buf && fread(buf, 1, (size_t)n, f) != (size_t)n) {
        free(buf);
        buf = NULL;
    }
    fclose(f);
    if (buf) buf[n] = 0;
    return buf;
}

static int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* Decodes hex into a new buffer; returns its length, or -1. */
static long unhex(const char *s, uint8_t **out) {
    size_t n = strlen(s);
    if (n % 2) return -1;
    uint8_t *b = malloc(n / 2 + 1);
    if (!b) return -1;
    for (size_t i = 0; i < n / 2; i++) {
        int hi = hex_value(s[2 * i]), lo = hex_value(s[2 * i + 1]);
        if (hi < 0 || lo < 0) {
            free(b);
            return -1;
        }
        b[i] = (uint8_t)(hi * 16 + lo);
    }
    *out = b;
    return (long)(n / 2);
}

static void fail_with(psao_decoder *d, const char *what, psao_result r) {
    char msg[512];
    size_t len = 0;
    if (psao_decoder_last_error(d, msg, sizeof msg, &len) != PSAO_OK) msg[0] = 0;
    fprintf(stderr, "%s: %s (%s)\n", what, psao_result_name(r), msg);
    exit(2);
}

/* The mirror's state in the listing form of spec/vectors/README.md. */
static void describe(psao_decoder *d, text *t) {
    uint32_t seq;
    psao_result r = psao_decoder_sequence(d, &seq);
    if (r == PSAO_OK)
        text_printf(t, "sequence %u\n", seq);
    else if (r == PSAO_ERROR_NO_STATE)
        text_printf(t, "sequence none\n");
    else
        fail_with(d, "sequence", r);

    size_t count = 0;
    r = psao_decoder_instance_ids(d, NULL, 0, &count);
    if (r != PSAO_OK && r != PSAO_ERROR_BUFFER_TOO_SHORT) fail_with(d, "instance_ids", r);
    uint32_t *ids = calloc(count ? count : 1, sizeof *ids);
    r = psao_decoder_instance_ids(d, ids, count, &count);
    if (r != PSAO_OK) fail_with(d, "instance_ids", r);

    for (size_t k = 0; k < count; k++) {
        uint32_t id = ids[k];
        psao_instance_info info;
        r = psao_decoder_instance(d, id, &info);
        if (r != PSAO_OK) fail_with(d, "instance", r);
        const psao_instance_def *def = &info.def;
        text_printf(t,
                    "instance %u origin %.9g %.9g %.9g cell_size %.9g %.9g %.9g dims %u %u %u "
                    "table_log2 %u bucket_capacity %u cell_capacity %u cell_pool %u "
                    "point_format %u%s radius %.9g t_n %.9g t_d %.9g\n",
                    id, def->origin[0], def->origin[1], def->origin[2], def->cell_size[0],
                    def->cell_size[1], def->cell_size[2], def->dims[0], def->dims[1], def->dims[2],
                    def->table_log2, def->bucket_capacity, def->cell_capacity, def->cell_pool,
                    def->point_format, def->overflow ? " overflow" : "", def->radius, def->t_n,
                    def->t_d);
        if (info.has_transform) {
            text_printf(t, "transform %u seq %u matrix", id, info.transform.sequence);
            for (int i = 0; i < 12; i++) text_printf(t, " %.9g", info.transform.matrix[i]);
            text_printf(t, "\n");
        }
        psao_bucket_entry *entries = calloc(info.bucket_entries ? info.bucket_entries : 1,
                                            sizeof *entries);
        r = psao_decoder_copy_buckets(d, id, 0, info.bucket_entries, entries);
        if (r != PSAO_OK) fail_with(d, "copy_buckets", r);
        for (uint32_t i = 0; i < info.bucket_entries; i++) {
            if (entries[i].key == 0xFFFFFFFFu) continue;
            text_printf(t, "bucket %u %u key %u cell %u\n", id, i / def->bucket_capacity,
                        entries[i].key, entries[i].cell);
        }
        free(entries);
        uint32_t *words = calloc(info.words ? info.words : 1, sizeof *words);
        r = psao_decoder_copy_words(d, id, 0, info.words, words);
        if (r != PSAO_OK) fail_with(d, "copy_words", r);
        for (uint32_t i = 0; i < info.words; i++) {
            if (!words[i]) continue;
            psao_point_fields f;
            if (psao_point_word_fields(words[i], &f) != PSAO_OK) exit(2);
            text_printf(t, "word %u cell %u slot %u %08x pos %u %u %u normal %02x ao %u\n", id,
                        i / def->cell_capacity, i % def->cell_capacity, words[i], f.position[0],
                        f.position[1], f.position[2], f.normal, f.ao);
        }
        free(words);
    }
    free(ids);
}

/* Whether a whole token is a number; its value as binary32 in *v. */
static int number(const char *tok, size_t n, float *v) {
    char buf[64];
    if (n == 0 || n >= sizeof buf) return 0;
    memcpy(buf, tok, n);
    buf[n] = 0;
    char *end;
    *v = strtof(buf, &end);
    return *end == 0;
}

/* Compares two listings token by token; prints the first difference. */
static int same_listing(const char *want, const char *got, const char *name) {
    const char *a = want, *b = got;
    int line = 1;
    for (;;) {
        while (*a == ' ' || *a == '\r') a++;
        while (*b == ' ') b++;
        if (*a == '\n' || *b == '\n') {
            if (*a != *b) break;
            a++, b++, line++;
            continue;
        }
        if (!*a || !*b) {
            while (*a == '\n' || *a == ' ' || *a == '\r') a++;
            if (!*a && !*b) return 1;
            break;
        }
        size_t na = strcspn(a, " \r\n"), nb = strcspn(b, " \n");
        float fa, fb;
        int equal = (na == nb && memcmp(a, b, na) == 0) ||
                    (number(a, na, &fa) && number(b, nb, &fb) && fa == fb);
        if (!equal) break;
        a += na, b += nb;
    }
    fprintf(stderr, "%s: state differs at line %d\n  want: %.*s\n  got:  %.*s\n", name, line,
            (int)strcspn(a, "\n"), a, (int)strcspn(b, "\n"), b);
    return 0;
}

/* Replays one vector; returns 1 when it passes. */
static int replay(const char *dir, const char *file) {
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, file);
    char *src = read_file(path);
    if (!src) {
        fprintf(stderr, "%s: cannot read\n", path);
        return 0;
    }
    psao_limits limits = psao_limits_default();
    psao_decoder *d = NULL;
    char outcome[256] = "";
    int ok = 1;
    char *state = NULL;
    for (char *line = src; line && *line && ok;) {
        char *next = strchr(line, '\n');
        if (next) *next++ = 0;
        size_t n = strlen(line);
        if (n && line[n - 1] == '\r') line[--n] = 0;
        char *rest = strchr(line, ' ');
        rest = rest ? rest + 1 : line + n;
        if (n == 0 || line[0] == '#') {
            /* comment */
        } else if (!strncmp(line, "limit ", 6)) {
            char name[64];
            unsigned long long v;
            if (sscanf(rest, "%63s %llu", name, &v) != 2) ok = 0;
            else if (!strcmp(name, "max_frame_bytes")) limits.max_frame_bytes = (uint32_t)v;
            else if (!strcmp(name, "max_payload_bytes")) limits.max_payload_bytes = (uint32_t)v;
            else if (!strcmp(name, "max_messages")) limits.max_messages = (uint32_t)v;
            else if (!strcmp(name, "max_instances")) limits.max_instances = (uint32_t)v;
            else if (!strcmp(name, "max_cell_pool")) limits.max_cell_pool = (uint32_t)v;
            else if (!strcmp(name, "max_table_log2")) limits.max_table_log2 = (uint8_t)v;
            else if (!strcmp(name, "max_mirror_bytes")) limits.max_mirror_bytes = v;
            else {
                fprintf(stderr, "%s: unknown limit %s\n", file, name);
                ok = 0;
            }
        } else if (!strncmp(line, "frame ", 6) || !strncmp(line, "digest ", 7)) {
            if (!d && psao_decoder_new(&limits, &d) != PSAO_OK) {
                fprintf(stderr, "%s: psao_decoder_new failed\n", file);
                ok = 0;
                break;
            }
            if (line[0] == 'f') {
                uint8_t *bytes = NULL;
                long len = unhex(rest, &bytes);
                if (len < 0) {
                    fprintf(stderr, "%s: bad hex\n", file);
                    ok = 0;
                    break;
                }
                psao_event ev;
                psao_result r = psao_decoder_receive(d, bytes, (size_t)len, &ev);
                free(bytes);
                if (r != PSAO_OK)
                    snprintf(outcome, sizeof outcome, "error %s", psao_result_name(r));
                else if (ev.kind == PSAO_EVENT_APPLIED)
                    snprintf(outcome, sizeof outcome, "applied %u %s", ev.sequence,
                             ev.keyframe ? "keyframe" : "delta");
                else if (ev.kind == PSAO_EVENT_STALE)
                    snprintf(outcome, sizeof outcome, "stale");
                else
                    snprintf(outcome, sizeof outcome, "need_keyframe");
            } else {
                uint32_t digest;
                char got[16];
                psao_result r = psao_decoder_digest(d, &digest);
                if (r == PSAO_OK)
                    snprintf(got, sizeof got, "%08x", digest);
                else if (r == PSAO_ERROR_NO_STATE)
                    snprintf(got, sizeof got, "none");
                else
                    fail_with(d, "digest", r);
                if (strcmp(got, rest)) {
                    fprintf(stderr, "%s: digest %s, want %s\n", file, got, rest);
                    ok = 0;
                }
            }
        } else if (!strncmp(line, "expect ", 7)) {
            if (strcmp(outcome, rest)) {
                fprintf(stderr, "%s: outcome `%s`, want `%s`\n", file, outcome, rest);
                ok = 0;
            }
            outcome[0] = 0;
        } else if (!strcmp(line, "state")) {
            state = next ? next : line + n;
            break;
        } else {
            fprintf(stderr, "%s: unknown line `%s`\n", file, line);
            ok = 0;
        }
        line = next;
    }
    if (ok && (!d || !state)) {
        fprintf(stderr, "%s: no frame or no state section\n", file);
        ok = 0;
    }
    if (ok) {
        text got = {0};
        describe(d, &got);
        ok = same_listing(state, got.data ? got.data : "", file);
        free(got.data);
    }
    psao_decoder_free(d);
    free(src);
    return ok;
}

static int by_name(const void *a, const void *b) {
    return strcmp(*(char *const *)a, *(char *const *)b);
}

int main(int argc, char **argv) {
    if (argc != 2) {
        fprintf(stderr, "usage: %s SPEC_VECTORS_DIR\n", argv[0]);
        return 2;
    }
    DIR *dir = opendir(argv[1]);
    if (!dir) {
        fprintf(stderr, "cannot open %s\n", argv[1]);
        return 2;
    }
    char **names = NULL;
    size_t count = 0;
    for (struct dirent *e; (e = readdir(dir));) {
        size_t n = strlen(e->d_name);
        if (n < 5 || strcmp(e->d_name + n - 4, ".txt")) continue;
        char **grown = realloc(names, (count + 1) * sizeof *names);
        if (!grown) return 2;
        names = grown;
        names[count++] = strdup(e->d_name);
    }
    closedir(dir);
    qsort(names, count, sizeof *names, by_name);
    size_t failed = 0;
    for (size_t i = 0; i < count; i++) {
        if (!replay(argv[1], names[i])) failed++;
        free(names[i]);
    }
    free(names);
    printf("psao %s: %zu vectors, %zu passed, %zu failed\n", psao_version(), count,
           count - failed, failed);
    return failed || count == 0 ? 1 : 0;
}
