/*
 * A device finder for OmApi that reports one emulated AX3/AX6 (stillpoint's test code).
 *
 * It takes the place of OmApi's udev finder (omapi-devicefinder-linux.c): where that finder pairs
 * a USB block device with the tty whose ID_SERIAL_SHORT is the USB serial, reads the device id as
 * the serial's trailing decimal number and reports "/media/<label>", this one is told the serial,
 * the pseudo-terminal and the drive folder of the emulated device and reports them through the
 * same OmDeviceDiscovery(OM_DEVICE_CONNECTED, id, serial, port, volume) call, once, when OmApi
 * starts its discovery. No thread: an emulated device does not come and go during a run.
 */

#include "omapi-internal.h"

#include "finder.h"

static char finder_serial[OM_MAX_SERIALID_LEN];
static char finder_port[OM_MAX_CDC_PATH];
static char finder_volume[OM_MAX_MSD_PATH];
static int finder_set;

unsigned int finder_id_from_serial(const char *serial)
{
    /* the trailing run of decimal digits, (unsigned)-1 when there is none (as the vendor's
       finders read a serial such as "CWA17_00123" or "AX664_0601234") */
    unsigned int value = (unsigned int)-1;
    int in_number = 0;
    const char *p;
    for (p = serial; *p != '\0'; p++) {
        if (*p >= '0' && *p <= '9') {
            if (!in_number) { value = 0; in_number = 1; }
            value = 10 * value + (unsigned int)(*p - '0');
        } else {
            in_number = 0;
        }
    }
    return value;
}

int finder_set_device(const char *serial, const char *port, const char *volume)
{
    if (strlen(serial) >= sizeof(finder_serial) || strlen(port) >= sizeof(finder_port)
            || strlen(volume) >= sizeof(finder_volume)) {
        return -1;
    }
    strcpy(finder_serial, serial);
    strcpy(finder_port, port);
    strcpy(finder_volume, volume);
    finder_set = 1;
    return 0;
}

void OmDeviceDiscoveryStart(void)
{
    if (finder_set) {
        OmDeviceDiscovery(OM_DEVICE_CONNECTED, finder_id_from_serial(finder_serial), finder_serial,
                          finder_port, finder_volume);
    }
}

void OmDeviceDiscoveryStop(void)
{
}
