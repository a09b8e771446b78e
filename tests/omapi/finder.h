/* The emulated-device finder that replaces OmApi's udev finder (see finder.c). */
#ifndef STILLPOINT_OMAPI_FINDER_H
#define STILLPOINT_OMAPI_FINDER_H

/* The device id OmApi uses: the trailing decimal number of the USB serial. */
unsigned int finder_id_from_serial(const char *serial);

/* The device that OmStartup's discovery will report; call before OmStartup. 0 or -1 (too long). */
int finder_set_device(const char *serial, const char *port, const char *volume);

#endif
