/*
 * The checksum of a serialized FMU state, shared by fmi2_framework.c and
 * fmi3_framework.c: CRC-32 (IEEE 802.3, reflected polynomial 0xEDB88320).
 * Each framework checksums its own header (with the crc field 0) and then
 * the model bytes, and refuses a state whose checksum differs.
 */
#ifndef SERIAL_CHECKSUM_H
#define SERIAL_CHECKSUM_H

#include <stddef.h>

/* CRC-32 of n bytes, continuing from crc (0 to start). */
static unsigned int crc32_update(unsigned int crc, const unsigned char *p, size_t n)
{
    size_t i;
    int k;
    crc = ~crc;
    for (i = 0; i < n; i++) {
        crc ^= p[i];
        for (k = 0; k < 8; k++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

#endif
