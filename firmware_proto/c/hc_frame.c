/* heliocal serial frame protocol v1: reference codec (see hc_frame.h). */
#include "hc_frame.h"

#include <string.h>

uint16_t hc_crc16(const uint8_t *data, size_t len)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    int bit;
    for (i = 0; i < len; i++) {
        crc ^= (uint16_t)(data[i] << 8);
        for (bit = 0; bit < 8; bit++) {
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
        }
    }
    return crc;
}

int hc_encode(const hc_frame *f, uint8_t *out, size_t cap)
{
    uint8_t body[HC_MAX_BODY];
    size_t n, i, code_at, o;
    uint8_t code;
    uint16_t crc;
    if (f == NULL || out == NULL || f->length > HC_MAX_PAYLOAD) {
        return HC_ERR_ARG;
    }
    body[0] = f->length;
    body[1] = f->address;
    body[2] = f->seq;
    body[3] = f->command;
    memcpy(body + 4, f->payload, f->length);
    n = 4u + f->length;
    crc = hc_crc16(body, n);
    body[n++] = (uint8_t)(crc & 0xFFu);
    body[n++] = (uint8_t)(crc >> 8);
    if (cap < n + 3u) { /* COBS adds one byte (body < 254), plus two delimiters */
        return HC_ERR_ARG;
    }
    out[0] = 0x00;
    code_at = 1;
    o = 2;
    code = 1;
    for (i = 0; i < n; i++) {
        if (body[i] == 0x00) {
            out[code_at] = code;
            code_at = o++;
            code = 1;
        } else {
            out[o++] = body[i];
            code++;
        }
    }
    out[code_at] = code;
    out[o++] = 0x00;
    return (int)o;
}

int hc_decode_stuffed(const uint8_t *chunk, size_t len, hc_frame *f)
{
    uint8_t body[HC_MAX_BODY];
    size_t i = 0, n = 0, end, k;
    uint16_t got;
    if (len == 0) {
        return HC_ERR_SHORT;
    }
    if (len > HC_MAX_ENCODED) {
        return HC_ERR_TOO_LONG;
    }
    while (i < len) {
        uint8_t code = chunk[i];
        if (code == 0) {
            return HC_ERR_COBS;
        }
        end = i + code;
        if (end > len) {
            return HC_ERR_COBS;
        }
        for (k = i + 1; k < end; k++) {
            if (chunk[k] == 0) {
                return HC_ERR_COBS;
            }
            body[n++] = chunk[k];
        }
        i = end;
        if (code != 0xFFu && i < len) {
            body[n++] = 0x00;
        }
    }
    if (n < HC_MIN_BODY) {
        return HC_ERR_SHORT;
    }
    got = (uint16_t)(body[n - 2] | (body[n - 1] << 8));
    if (got != hc_crc16(body, n - 2)) {
        return HC_ERR_CRC;
    }
    if (body[0] != n - HC_MIN_BODY) {
        return HC_ERR_LENGTH;
    }
    f->length = body[0];
    f->address = body[1];
    f->seq = body[2];
    f->command = body[3];
    memcpy(f->payload, body + 4, f->length);
    return HC_OK;
}

int hc_decode(const uint8_t *wire, size_t len, hc_frame *f)
{
    while (len > 0 && wire[0] == 0x00) {
        wire++;
        len--;
    }
    while (len > 0 && wire[len - 1] == 0x00) {
        len--;
    }
    return hc_decode_stuffed(wire, len, f);
}

const char *hc_reason(int status)
{
    switch (status) {
    case HC_OK: return "ok";
    case HC_ERR_COBS: return "cobs";
    case HC_ERR_TOO_LONG: return "too_long";
    case HC_ERR_SHORT: return "short";
    case HC_ERR_CRC: return "crc";
    case HC_ERR_LENGTH: return "length";
    default: return "arg";
    }
}

void hc_decoder_init(hc_decoder *d)
{
    d->len = 0;
    d->overflow = 0;
}

int hc_decoder_feed(hc_decoder *d, uint8_t byte, hc_frame *out)
{
    int rc;
    if (byte != 0x00) {
        if (d->len < HC_MAX_ENCODED) {
            d->buf[d->len++] = byte;
        } else {
            d->overflow = 1;
        }
        return 0;
    }
    if (d->overflow) {
        rc = HC_ERR_TOO_LONG;
    } else if (d->len == 0) {
        rc = 0; /* back-to-back delimiters: nothing between them */
    } else {
        rc = hc_decode_stuffed(d->buf, d->len, out);
        rc = (rc == HC_OK) ? 1 : rc;
    }
    d->len = 0;
    d->overflow = 0;
    return rc;
}
