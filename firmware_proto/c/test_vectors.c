/* Host test of the C codec against the shared vectors (firmware_proto/vectors/frames.json).
 * vectors.h is generated from the JSON by tests/serial/test_c_codec.py (or `make test`). */
#include <stdio.h>
#include <string.h>

#include "hc_frame.h"

typedef struct {
    const char *name;
    uint8_t address, seq, command;
    const uint8_t *payload;
    size_t payload_len;
    const uint8_t *wire;
    size_t wire_len;
} valid_vector;

typedef struct {
    const char *name;
    const uint8_t *wire;
    size_t wire_len;
    const char *reason;
} invalid_vector;

typedef struct {
    const uint8_t *data;
    size_t len;
    uint16_t crc;
} crc_vector;

#include "vectors.h"

static int failures = 0;

#define CHECK(cond, ...)                                      \
    do {                                                      \
        if (!(cond)) {                                        \
            failures++;                                       \
            printf("FAIL %s:%d: ", __FILE__, __LINE__);      \
            printf(__VA_ARGS__);                              \
            printf("\n");                                     \
        }                                                     \
    } while (0)

static const uint8_t garbage[] = {0x13, 0xFF, 0x00, 0x05, 0x77, 0x02, 0x00, 0x00, 0xA5};

int main(void)
{
    size_t i, k;
    for (i = 0; i < N_CRC; i++) {
        CHECK(hc_crc16(CRC_VECTORS[i].data, CRC_VECTORS[i].len) == CRC_VECTORS[i].crc,
              "crc vector %u", (unsigned)i);
    }
    for (i = 0; i < N_VALID; i++) {
        const valid_vector *v = &VALID[i];
        hc_frame f, g;
        hc_decoder d;
        uint8_t out[HC_MAX_WIRE];
        int n, got = 0, rc;
        memset(&f, 0, sizeof f);
        f.address = v->address;
        f.seq = v->seq;
        f.command = v->command;
        f.length = (uint8_t)v->payload_len;
        memcpy(f.payload, v->payload, v->payload_len);
        n = hc_encode(&f, out, sizeof out);
        CHECK(n == (int)v->wire_len && memcmp(out, v->wire, v->wire_len) == 0, "encode %s", v->name);
        rc = hc_decode(v->wire, v->wire_len, &g);
        CHECK(rc == HC_OK, "decode %s: %s", v->name, hc_reason(rc));
        CHECK(rc != HC_OK || (g.address == v->address && g.seq == v->seq && g.command == v->command
                              && g.length == v->payload_len
                              && memcmp(g.payload, v->payload, v->payload_len) == 0),
              "decode %s: fields", v->name);
        /* Streaming, byte by byte, after garbage: exactly this frame comes out last. */
        hc_decoder_init(&d);
        for (k = 0; k < sizeof garbage; k++) {
            (void)hc_decoder_feed(&d, garbage[k], &g);
        }
        for (k = 0; k < v->wire_len; k++) {
            if (hc_decoder_feed(&d, v->wire[k], &g) == 1) {
                got++;
            }
        }
        CHECK(got == 1 && g.seq == v->seq && g.length == v->payload_len, "stream %s", v->name);
    }
    for (i = 0; i < N_INVALID; i++) {
        hc_frame g;
        int rc = hc_decode(INVALID[i].wire, INVALID[i].wire_len, &g);
        CHECK(strcmp(hc_reason(rc), INVALID[i].reason) == 0, "invalid %s: got %s, want %s",
              INVALID[i].name, hc_reason(rc), INVALID[i].reason);
    }
    printf("c codec: %u crc, %u valid, %u invalid vectors, %d failures\n", (unsigned)N_CRC,
           (unsigned)N_VALID, (unsigned)N_INVALID, failures);
    return failures ? 1 : 0;
}
