/* heliocal serial frame protocol v1: reference codec in C99 (firmware_proto/PROTOCOL.md).
 *
 * Wire: 0x00 | COBS(LEN ADDR SEQ CMD PAYLOAD[LEN] CRC_lo CRC_hi) | 0x00
 * CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0; check 0x29B1 for
 * "123456789") over LEN..PAYLOAD, sent low byte first. No dynamic allocation anywhere.
 */
#ifndef HC_FRAME_H
#define HC_FRAME_H

#include <stddef.h>
#include <stdint.h>

#define HC_MAX_PAYLOAD 64
#define HC_MIN_BODY 6
#define HC_MAX_BODY (4 + HC_MAX_PAYLOAD + 2) /* 70 */
#define HC_MAX_ENCODED (HC_MAX_BODY + 1)     /* 71: one COBS code byte per 254 */
#define HC_MAX_WIRE (HC_MAX_ENCODED + 2)     /* 73 with both delimiters */
#define HC_REPLY_BIT 0x80u

/* Decoder results; hc_reason() gives the strings of the shared test vectors. */
enum {
    HC_OK = 0,
    HC_ERR_COBS = -1,     /* "cobs": code byte past the end, or 0x00 inside a frame */
    HC_ERR_TOO_LONG = -2, /* "too_long": more than HC_MAX_ENCODED bytes between delimiters */
    HC_ERR_SHORT = -3,    /* "short": fewer than 6 body bytes */
    HC_ERR_CRC = -4,      /* "crc": CRC mismatch */
    HC_ERR_LENGTH = -5,   /* "length": LEN disagrees with the body length */
    HC_ERR_ARG = -6       /* encoder: bad argument or output buffer too small */
};

typedef struct {
    uint8_t address; /* 1..247, 0 reserved */
    uint8_t seq;
    uint8_t command; /* bit 7 set on replies */
    uint8_t length;  /* payload bytes, 0..HC_MAX_PAYLOAD */
    uint8_t payload[HC_MAX_PAYLOAD];
} hc_frame;

typedef struct {
    uint8_t buf[HC_MAX_ENCODED];
    size_t len;
    int overflow;
} hc_decoder;

uint16_t hc_crc16(const uint8_t *data, size_t len);
/* Writes the wire bytes (with both delimiters) to out; returns their count or HC_ERR_ARG. */
int hc_encode(const hc_frame *f, uint8_t *out, size_t cap);
/* Decodes the bytes between two delimiters (no 0x00 inside). Returns HC_OK or HC_ERR_*. */
int hc_decode_stuffed(const uint8_t *chunk, size_t len, hc_frame *f);
/* Decodes one frame given with or without its surrounding delimiters. */
int hc_decode(const uint8_t *wire, size_t len, hc_frame *f);
const char *hc_reason(int status);

void hc_decoder_init(hc_decoder *d);
/* Feed one received byte. Returns 1 when *out holds a new valid frame, 0 when more bytes are
 * needed, or HC_ERR_* when the chunk that just ended was rejected (the decoder has already
 * resynchronised and continues with the next byte). */
int hc_decoder_feed(hc_decoder *d, uint8_t byte, hc_frame *out);

#endif
