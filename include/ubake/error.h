/* ubake/error.h — result codes and the message callback shared by every module.
 *
 * Every fallible call returns a ub_result. Library code never prints and never exits:
 * messages with context (file, node, value) go to a ub_log the caller passes in.
 * A NULL ub_log (or a NULL fn) drops messages. Thread safety: the callback may be
 * called from several threads at once only where a function says so.
 */
#ifndef UBAKE_ERROR_H
#define UBAKE_ERROR_H

#ifdef __cplusplus
extern "C" {
#endif

typedef enum ub_result {
  UB_OK = 0,
  UB_ERR_INVALID_ARGUMENT,
  UB_ERR_INVALID_DATA,
  UB_ERR_IO,
  UB_ERR_OUT_OF_MEMORY,
  UB_ERR_UNSUPPORTED_VERSION,
  UB_ERR_CANCELLED,
  UB_ERR_NOT_BAKED,
  UB_ERR_EXTERNAL
} ub_result;

typedef enum ub_log_level {
  UB_LOG_ERROR = 0,
  UB_LOG_WARNING,
  UB_LOG_INFO
} ub_log_level;

typedef void (*ub_log_fn)(void *user, ub_log_level level, const char *message);

typedef struct ub_log {
  ub_log_fn fn;
  void *user;
} ub_log;

/* Short, static, human-readable name of a result ("invalid data"). Never NULL. */
const char *ub_result_string(ub_result r);

/* printf-style message to log (NULL-safe). */
#if defined(__GNUC__)
__attribute__((format(printf, 3, 4)))
#endif
void ub_log_printf(const ub_log *log, ub_log_level level, const char *fmt, ...);

#ifdef __cplusplus
}
#endif
#endif
