/* fileio.c — whole-file reads (see fileio.h). The file is opened non-blocking: opening a FIFO
 * for reading would otherwise wait for a writer forever, before fstat could reject it. */
#include "input/fileio.h"

#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

bool fileio_read_all(const char *path, const char *what, const char *name, size_t max_bytes, char **data,
                     size_t *size, struct err *err)
{
    *data = NULL;
    *size = 0;
    if (!name) name = path;
    int fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
    if (fd < 0) {
        int e = errno;
        if (e == ENOENT || e == ENOTDIR) return err_set(err, ERR_NOT_FOUND, name, "%s '%s' not found", what, name);
        return err_set(err, ERR_IO, name, "cannot open %s '%s': %s", what, name, strerror(e));
    }
    struct stat st;
    if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
        close(fd);
        return err_set(err, ERR_IO, name, "%s '%s' is not a regular file", what, name);
    }
    if ((uint64_t)st.st_size > max_bytes) {
        close(fd);
        return err_set(err, ERR_LIMIT, name, "%s '%s' is %lld bytes, more than the limit of %zu", what, name,
                       (long long)st.st_size, max_bytes);
    }
    size_t want = (size_t)st.st_size;
    char *buf = malloc(want + 1);
    if (!buf) {
        close(fd);
        return err_set(err, ERR_NOMEM, name, "out of memory reading %s '%s'", what, name);
    }
    size_t got = 0;
    while (got < want) {
        ssize_t r = read(fd, buf + got, want - got);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) break;
        got += (size_t)r;
    }
    close(fd);
    if (got != want) {
        free(buf);
        return err_set(err, ERR_IO, name, "cannot read %s '%s' (%zu of %zu bytes)", what, name, got, want);
    }
    buf[want] = '\0';
    *data = buf;
    *size = want;
    return true;
}
