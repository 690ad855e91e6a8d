/* piezopreload: the rig's fixed-rate loop in a native thread (see rig/native_loop.py).

   One cycle k has the absolute deadline t0 + k dt; the thread sleeps to it with
   clock_nanosleep(TIMER_ABSTIME) on CLOCK_MONOTONIC (or, for a run back to back, advances a
   virtual clock to it), reads the force, tests the interlock table, runs the compiled
   controller step, tests the table's command rows, clamps and slew-limits the command, writes
   it, toggles the heartbeat and puts the sample into a single-producer/single-consumer ring
   buffer that the Python supervisor drains. Nothing in a cycle takes a lock, allocates or
   calls Python.

   The interlocks are not written here: the loop receives the rows of rig/interlocks.py
   (stage, quantity, test, cause, limits) and tests them in their order; the codes of the
   stages, quantities, tests and causes are #define lines generated from that module and put
   before this source when it is built. A stop ramps the voltage to the safe level at the
   loop's rate and disarms. The Python loop tests the same rows: the two loops give the same
   samples and the same events for a simulated run (tests/test_native_loop.py). */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

#define PP_COLS 14
#define PP_MAX_FAULTS 16

typedef int (*pp_step_fn)(double, double, double, double*, const double*, double*);
typedef int (*pp_start_fn)(double, double, double, double, const double*, double*);
typedef int (*pp_plant_read_fn)(const double*, const double*, double, double*);
typedef int (*pp_plant_write_fn)(double*, const double*, double);
typedef int (*hw_arm_fn)(void);
typedef int (*hw_read_fn)(double, double*, double*);
typedef int (*hw_write_fn)(double);
typedef int (*hw_disarm_fn)(void);
typedef int (*hw_heartbeat_fn)(int);

/* fault kinds: F_NAN, F_STALE, ... are defined before this source, from rig/backends.py FAULT_KINDS */
/* where an exception came from */
enum { X_ARM = 1, X_READ, X_WRITE, X_STEP, X_START, X_FAULT };

typedef struct { int32_t kind, fired; double at_s, value, duration_s; } pp_fault;
/* one interlock: cause trips when test holds for quantity at stage (rig/interlocks.py rows) */
typedef struct { int32_t stage, quantity, test, cause; double lo, hi; } pp_interlock;

typedef struct {
  /* ---- set before the start ---- */
  double dt_s; int64_t n_ref; const double* ref; const double* extra; /* ff_extra per sample, or NULL */
  int32_t hold, realtime; /* realtime 0: back to back on a virtual clock */
  double v_min, v_max, slew_V_per_s, ramp_s, safe_V, stall_report_s;
  pp_interlock interlocks[PP_MAX_INTERLOCKS]; int32_t n_interlocks;
  /* two slots: the controller running and the next; each its step, start, state and parameters (a gain set of
     another structure brings its own step and start, and a state of its own size) */
  pp_step_fn step[2]; pp_start_fn start[2]; double* state[2]; double* params[2];
  int32_t backend; /* 0: the simulated plant, 1: a C-ABI library */
  pp_plant_read_fn plant_read; pp_plant_write_fn plant_write; double* plant_state; const double* plant_params;
  const double* noise; int64_t n_noise;
  hw_arm_fn hw_arm; hw_read_fn hw_read; hw_write_fn hw_write; hw_disarm_fn hw_disarm; hw_heartbeat_fn hw_heartbeat;
  uint64_t* heartbeat; double* daq_V; /* the simulated DAQ's shared memory, or NULL */
  pp_fault faults[PP_MAX_FAULTS]; int32_t n_faults;
  int32_t want_fifo, fifo_priority, want_mlock, spin_ns;
  double* ring; int64_t ring_rows;
  double* stalls; int64_t stall_rows; /* (t_s, held_s) of each stall, a ring */
  /* ---- shared: ring indices, requests ---- */
  int64_t head, tail, lost, n_stalls;
  int32_t active, taken;   /* the parameter buffer Python asks for; the one the loop runs */
  int32_t stop, stop_signal; /* 1 trip (signal), 2 end completed */
  /* ---- status, written by the loop ---- */
  int32_t started, finished, fifo_errno, mlock_errno;
  int64_t cycles, missed, clamped, switches;
  double switch_t, held_max;
  int32_t trip_cause, trip_where; double trip_t, trip_value, trip_v;
  double v_end, t_end; int32_t ramp_failed; double ramp_failed_t;
  double latest_t, latest_sp, latest_y, latest_v; int32_t latest_mode; /* 0 running, 1 ramp, 2 done */
  pthread_t thread;
  /* ---- the loop's own ---- */
  double last_force, last_sample_t; int64_t noise_k, vclock;
} pp_loop;

static int64_t now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void sleep_until(int64_t t_ns) {
  struct timespec ts;
  ts.tv_sec = t_ns / 1000000000LL;
  ts.tv_nsec = t_ns % 1000000000LL;
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {}
}

/* the wait of a cycle: sleep to the deadline (the last spin_ns spun), as the host check waits too */
static int64_t wait_until(int64_t deadline, int32_t spin_ns) {
  int64_t t;
  if (spin_ns > 0) {
    if (deadline - now_ns() > spin_ns) sleep_until(deadline - spin_ns);
    while ((t = now_ns()) < deadline) {}
    return t;
  }
  sleep_until(deadline);
  return now_ns();
}

/* the loop's clock: the monotonic clock in real time, else a virtual one that only waits and stalls move */
static int64_t clock_now(const pp_loop* L) { return L->realtime ? now_ns() : L->vclock; }

static int64_t clock_wait(pp_loop* L, int64_t deadline) {
  if (L->realtime) return wait_until(deadline, L->spin_ns);
  if (L->vclock < deadline) L->vclock = deadline;
  return L->vclock;
}

static void clock_stall(pp_loop* L, double seconds) {
  if (L->realtime) sleep_until(now_ns() + llround(seconds * 1e9));
  else L->vclock += llround(seconds * 1e9);
}

static void push_row(pp_loop* L, const double* row) {
  int64_t h = L->head, t;
  for (;;) {
    t = __atomic_load_n(&L->tail, __ATOMIC_ACQUIRE);
    if (h - t < L->ring_rows) break;
    if (L->realtime) { __atomic_add_fetch(&L->lost, 1, __ATOMIC_RELAXED); return; }
    sleep_until(now_ns() + 200000); /* back to back: wait for the supervisor to drain */
  }
  memcpy(L->ring + (h % L->ring_rows) * PP_COLS, row, PP_COLS * sizeof(double));
  __atomic_store_n(&L->head, h + 1, __ATOMIC_RELEASE);
}

static void log_row(pp_loop* L, int64_t* rows, double t, double sp, double y, double u, double v, double ff, double p,
                    double i, double d, double period, double late, double compute, int miss, int mode) {
  double r[PP_COLS] = {t, sp, y, u, v, ff, p, i, d, period, late, compute, (double)miss, (double)mode};
  push_row(L, r);
  ++*rows;
}

static void record_stall(pp_loop* L, double t, double held) {
  int64_t n = L->n_stalls, j = n % L->stall_rows;
  L->stalls[2 * j] = t;
  L->stalls[2 * j + 1] = held;
  __atomic_store_n(&L->n_stalls, n + 1, __ATOMIC_RELEASE);
}

/* ---- the backend: the simulated plant or a C-ABI library, with injected faults ---- */

static int raw_read(pp_loop* L, double t, double* f, double* ts) {
  if (L->backend == 1) return L->hw_read(t, f, ts);
  double out[2], z = L->n_noise ? L->noise[L->noise_k % L->n_noise] : 0.0;
  int rc;
  ++L->noise_k;
  rc = L->plant_read(L->plant_state, L->plant_params, z, out);
  *f = out[1];
  *ts = t;
  return rc;
}

static int active_fault(const pp_fault* f, double t) { return f->at_s <= t && t < f->at_s + f->duration_s; }

static int read_force(pp_loop* L, double t, double* f, double* ts) {
  int j, stale = 0, rc;
  for (j = 0; j < L->n_faults; ++j) {
    pp_fault* F = &L->faults[j];
    if (!active_fault(F, t)) continue;
    if (F->kind == F_RAISE) return -1000;
    if (F->kind == F_DELAY) clock_stall(L, F->value);
    if (F->kind == F_SIGNAL && !F->fired) { /* to this thread: handled before the call returns */
      F->fired = 1;
      pthread_kill(pthread_self(), F->value ? (int)F->value : SIGTERM);
    }
    if (F->kind == F_STALE) stale = 1;
  }
  if (stale && !isnan(L->last_sample_t)) { *f = L->last_force; *ts = L->last_sample_t; return 0; }
  rc = raw_read(L, t, f, ts);
  if (rc) return rc;
  L->last_force = *f;
  L->last_sample_t = *ts;
  for (j = 0; j < L->n_faults; ++j) {
    const pp_fault* F = &L->faults[j];
    if (!active_fault(F, t)) continue;
    if (F->kind == F_NAN) *f = NAN;
    else if (F->kind == F_OFFSET) *f += F->value;
    else if (F->kind == F_READING) *f = F->value;
  }
  return 0;
}

static int write_voltage(pp_loop* L, double v) {
  int rc = L->backend == 1 ? L->hw_write(v) : L->plant_write(L->plant_state, L->plant_params, v);
  if (rc == 0 && L->daq_V) __atomic_store(L->daq_V, &v, __ATOMIC_RELEASE);
  return rc;
}

static void heartbeat(pp_loop* L, int64_t k) {
  if (L->heartbeat) __atomic_add_fetch(L->heartbeat, 1, __ATOMIC_RELEASE);
  if (L->backend == 1 && L->hw_heartbeat) L->hw_heartbeat((int)(k & 1));
}

/* the interlock rows of one stage, in their order: the cause of the first that holds (0: none) and its value */
static int check(const pp_loop* L, int stage, const double* q, double* value) {
  int j, hit;
  for (j = 0; j < L->n_interlocks; ++j) {
    const pp_interlock* r = &L->interlocks[j];
    double x;
    if (r->stage != stage) continue;
    x = q[r->quantity];
    switch (r->test) {
      case PP_TEST_NAN: hit = isnan(x); break;
      case PP_TEST_ABOVE: hit = x > r->lo; break;
      case PP_TEST_BELOW: hit = x < r->lo; break;
      case PP_TEST_OUTSIDE: hit = !(r->lo < x && x < r->hi); break;
      default: hit = !isfinite(x); break;
    }
    if (hit) { *value = x; return r->cause; }
  }
  return 0;
}

static void trip(pp_loop* L, int cause, int where, double t, double value, double v) {
  L->trip_cause = cause; L->trip_where = where; L->trip_t = t; L->trip_value = value; L->trip_v = v;
}

static void ramp_down(pp_loop* L, int64_t* rows, double v_from, int64_t t0, int64_t dt_ns) {
  double dt = L->dt_s, v = v_from, t, y, ts;
  int64_t n = v_from == L->safe_V ? 0 : (int64_t)ceil(L->ramp_s / dt), j, k0 = *rows - 1;
  if (n < 1 && v_from != L->safe_V) n = 1;
  t = (k0 > 0 ? k0 : 0) * dt;
  L->latest_mode = 1;
  for (j = 1; j <= n; ++j) {
    t = (k0 + j) * dt;
    clock_wait(L, t0 + (k0 + j) * dt_ns);
    v = j == n ? L->safe_V : v_from + (L->safe_V - v_from) * (double)j / (double)n;
    if (read_force(L, t, &y, &ts)) y = NAN;
    if (write_voltage(L, v)) {
      L->ramp_failed = 1; L->ramp_failed_t = t;
      if (write_voltage(L, L->safe_V) == 0) v = L->safe_V;
      break;
    }
    heartbeat(L, k0 + j);
    log_row(L, rows, t, NAN, y, NAN, v, NAN, NAN, NAN, NAN, dt, 0.0, 0.0, 0, 1);
    L->latest_t = t; L->latest_sp = NAN; L->latest_y = y; L->latest_v = v;
  }
  L->v_end = v;
  L->t_end = t;
}

/* what a cycle carries from one to the next */
typedef struct {
  int64_t t0, dt_ns, k, rows, wake_prev, last_write;
  double v_last;
  int need_start, p_idx;
  const double* params;
  pp_step_fn step; pp_start_fn start; double* state; /* the slot p_idx's */
} pp_cycle;

/* a new gain set asked for: taken at this cycle boundary, started bumplessly before the step */
static void take_switch(pp_loop* L, pp_cycle* c, double t) {
  int want = __atomic_load_n(&L->active, __ATOMIC_ACQUIRE);
  if (want == c->p_idx) return;
  c->p_idx = want; c->params = L->params[want]; c->need_start = 1;
  c->step = L->step[want]; c->start = L->start[want]; c->state = L->state[want];
  L->switch_t = t;
  __atomic_store_n(&L->taken, want, __ATOMIC_RELEASE);
  __atomic_add_fetch(&L->switches, 1, __ATOMIC_RELEASE);
}

/* one cycle of control; 0 to go on, 1 to stop (the trip, if any, recorded) */
static int cycle(pp_loop* L, pp_cycle* c) {
  double dt = L->dt_s, t = c->k * dt, y, ts, u, v, value, out[5], q[PP_N_QUANTITIES];
  double slew = L->slew_V_per_s * dt, sp, fx, late, period;
  int64_t deadline = c->t0 + c->k * c->dt_ns, wake, done;
  int cause, rc, stop, miss;
  sp = L->ref[c->k < L->n_ref ? c->k : L->n_ref - 1];
  fx = L->extra ? L->extra[c->k < L->n_ref ? c->k : L->n_ref - 1] : 0.0;
  wake = clock_wait(L, deadline);
  take_switch(L, c, t);
  stop = __atomic_load_n(&L->stop, __ATOMIC_ACQUIRE);
  late = (wake - deadline) * 1e-9;
  period = (wake - c->wake_prev) * 1e-9;
  if (stop) { /* this cycle is the stop's: logged, no reading, no command */
    log_row(L, &c->rows, t, sp, NAN, NAN, c->v_last, NAN, NAN, NAN, NAN, period, late, 0.0, 0, 2);
    if (stop == 1) trip(L, PP_T_SIGNAL, 0, t, L->stop_signal, c->v_last);
    else L->trip_t = t;
    return 1;
  }
  if ((rc = read_force(L, t, &y, &ts)) != 0) { trip(L, PP_T_EXCEPTION, X_READ, t, rc, c->v_last); return -1; }
  q[PP_Q_FORCE_N] = y; q[PP_Q_SAMPLE_AGE_S] = t - ts;
  q[PP_Q_HELD_S] = (clock_now(L) - c->last_write) * 1e-9; q[PP_Q_COMMAND_V] = NAN;
  if (q[PP_Q_HELD_S] > L->held_max) L->held_max = q[PP_Q_HELD_S];
  if (q[PP_Q_HELD_S] > L->stall_report_s) record_stall(L, t, q[PP_Q_HELD_S]);
  if ((cause = check(L, PP_STAGE_READING, q, &value)) != 0) {
    trip(L, cause, 0, t, value, c->v_last);
    log_row(L, &c->rows, t, sp, y, NAN, c->v_last, NAN, NAN, NAN, NAN, period, late, 0.0, 0, 2);
    return 1;
  }
  if (c->need_start) { /* bumpless: the first command of a start or a new gain set is the last one written */
    if ((rc = c->start(sp, y, c->v_last, fx, c->params, c->state)) != 0) {
      trip(L, PP_T_EXCEPTION, X_START, t, rc, c->v_last);
      return -1;
    }
    c->need_start = 0;
  }
  if ((rc = c->step(sp, y, fx, c->state, c->params, out)) != 0) { trip(L, PP_T_EXCEPTION, X_STEP, t, rc, c->v_last); return -1; }
  u = out[0];
  q[PP_Q_COMMAND_V] = u;
  if ((cause = check(L, PP_STAGE_COMMAND, q, &value)) != 0) {
    trip(L, cause, 0, t, value, c->v_last);
    log_row(L, &c->rows, t, sp, y, u, c->v_last, out[4], out[1], out[2], out[3], period, late, 0.0, 0, 2);
    return 1;
  }
  v = fmin(fmax(u, L->v_min), L->v_max);
  v = fmin(fmax(v, c->v_last - slew), c->v_last + slew);
  if (v != u) ++L->clamped;
  if ((rc = write_voltage(L, v)) != 0) { trip(L, PP_T_EXCEPTION, X_WRITE, t, rc, c->v_last); return -1; }
  c->last_write = clock_now(L);
  heartbeat(L, c->k);
  c->v_last = v;
  done = clock_now(L);
  miss = done > deadline + c->dt_ns;
  L->missed += miss;
  log_row(L, &c->rows, t, sp, y, u, v, out[4], out[1], out[2], out[3], period, late, (done - wake) * 1e-9, miss, 0);
  c->wake_prev = wake;
  L->latest_t = t; L->latest_sp = sp; L->latest_y = y; L->latest_v = v;
  ++c->k;
  L->cycles = c->k;
  return 0;
}

static void* run(void* arg) {
  pp_loop* L = (pp_loop*)arg;
  pp_cycle c;
  int rc, how = 0;

  prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0); /* wake at the deadline, not up to 50 us after it */
  memset(&c, 0, sizeof c);
  L->last_force = NAN; L->last_sample_t = NAN; L->noise_k = 0; L->vclock = 0;
  c.dt_ns = (int64_t)llround(L->dt_s * 1e9);
  c.v_last = L->safe_V;
  c.need_start = 1;
  c.p_idx = __atomic_load_n(&L->active, __ATOMIC_ACQUIRE);
  c.params = L->params[c.p_idx];
  c.step = L->step[c.p_idx]; c.start = L->start[c.p_idx]; c.state = L->state[c.p_idx];
  L->taken = c.p_idx;
  __atomic_store_n(&L->started, 1, __ATOMIC_RELEASE);
  if (L->backend == 1 && L->hw_arm && (rc = L->hw_arm()) != 0) {
    trip(L, PP_T_EXCEPTION, X_ARM, 0.0, rc, c.v_last);
    log_row(L, &c.rows, 0.0, NAN, NAN, NAN, c.v_last, NAN, NAN, NAN, NAN, 0.0, 0.0, 0.0, 0, 2);
    goto stop;
  }
  c.t0 = c.wake_prev = c.last_write = clock_now(L);
  while (how == 0) {
    if (c.k >= L->n_ref && !L->hold) break;
    how = cycle(L, &c);
  }
  if (how < 0) /* an exception: the cycle that raised is logged, no reading, no command */
    log_row(L, &c.rows, L->trip_t, NAN, NAN, NAN, c.v_last, NAN, NAN, NAN, NAN, 0.0, 0.0, 0.0, 0, 2);
stop:
  L->cycles = c.k;
  if (c.rows == 0) c.t0 = clock_now(L);
  ramp_down(L, &c.rows, c.v_last, c.t0, c.dt_ns);
  if (L->backend == 1 && L->hw_disarm) L->hw_disarm();
  L->latest_mode = 2;
  __atomic_store_n(&L->finished, 1, __ATOMIC_RELEASE);
  return NULL;
}

/* ---- signals: SIGINT and SIGTERM stop the loop here, then go on to the handler they had ---- */
static pp_loop* volatile signalled_loop = NULL;
static struct sigaction previous[2];

static void on_signal(int signo, siginfo_t* info, void* ctx) {
  pp_loop* L = signalled_loop;
  struct sigaction* old = &previous[signo == SIGINT ? 0 : 1];
  if (L) {
    L->stop_signal = signo;
    __atomic_store_n(&L->stop, 1, __ATOMIC_RELEASE);
  }
  if (old->sa_flags & SA_SIGINFO) {
    if (old->sa_sigaction) old->sa_sigaction(signo, info, ctx);
  } else if (old->sa_handler != SIG_DFL && old->sa_handler != SIG_IGN) {
    old->sa_handler(signo);
  }
}

int pp_loop_catch_signals(pp_loop* L) {
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_sigaction = on_signal;
  sa.sa_flags = SA_SIGINFO | SA_RESTART;
  sigemptyset(&sa.sa_mask);
  signalled_loop = L;
  if (sigaction(SIGINT, &sa, &previous[0]) || sigaction(SIGTERM, &sa, &previous[1])) return errno;
  return 0;
}

int pp_loop_release_signals(void) {
  signalled_loop = NULL;
  if (sigaction(SIGINT, &previous[0], NULL) || sigaction(SIGTERM, &previous[1], NULL)) return errno;
  return 0;
}

/* lock the process's pages in memory (before arming: locking a large process takes a while) */
int pp_loop_lock_memory(pp_loop* L) {
  L->mlock_errno = L->want_mlock ? (mlockall(MCL_CURRENT) ? errno : 0) : -1;
  return L->mlock_errno;
}

/* a thread running fn: SCHED_FIFO at priority where asked and permitted; *fifo_errno: -1 not asked, 0 granted */
static int start_thread(pthread_t* thread, int want_fifo, int priority, void* (*fn)(void*), void* arg,
                        int32_t* fifo_errno) {
  pthread_attr_t attr;
  struct sched_param sp;
  int rc;
  *fifo_errno = -1;
  if (want_fifo) {
    pthread_attr_init(&attr);
    pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED);
    pthread_attr_setschedpolicy(&attr, SCHED_FIFO);
    memset(&sp, 0, sizeof sp);
    sp.sched_priority = priority;
    pthread_attr_setschedparam(&attr, &sp);
    rc = pthread_create(thread, &attr, fn, arg);
    pthread_attr_destroy(&attr);
    *fifo_errno = rc;
    if (rc == 0) return 0;
  }
  return pthread_create(thread, NULL, fn, arg);
}

/* start the loop's thread: SCHED_FIFO and locked memory where permitted (errno kept, not fatal) */
int pp_loop_start(pp_loop* L) { return start_thread(&L->thread, L->want_fifo, L->fifo_priority, run, L, &L->fifo_errno); }

int pp_loop_join(pp_loop* L) {
  int rc = pthread_join(L->thread, NULL);
  if (L->mlock_errno == 0) munlockall();
  return rc;
}

/* the supervisor's side of the ring: up to max_rows samples into out; returns how many */
int64_t pp_loop_drain(pp_loop* L, double* out, int64_t max_rows) {
  int64_t h = __atomic_load_n(&L->head, __ATOMIC_ACQUIRE), t = L->tail, n = h - t, j;
  if (n > max_rows) n = max_rows;
  for (j = 0; j < n; ++j) memcpy(out + j * PP_COLS, L->ring + ((t + j) % L->ring_rows) * PP_COLS, PP_COLS * sizeof(double));
  __atomic_store_n(&L->tail, t + n, __ATOMIC_RELEASE);
  return n;
}

/* the stalls recorded so far (the supervisor reads those it has not seen from the stall ring) */
int64_t pp_loop_stalls(pp_loop* L) { return __atomic_load_n(&L->n_stalls, __ATOMIC_ACQUIRE); }

/* a new parameter vector is in the buffer that does not run; the loop takes it at its next cycle */
void pp_loop_switch(pp_loop* L, int32_t index) { __atomic_store_n(&L->active, index, __ATOMIC_RELEASE); }

void pp_loop_stop(pp_loop* L, int32_t how) { __atomic_store_n(&L->stop, how, __ATOMIC_RELEASE); }

int64_t pp_loop_sizeof(void) { return (int64_t)sizeof(pp_loop); }

/* ---- the host check: a bare thread waking as the loop waits, nothing else (rig/hostcheck.py) ---- */
typedef struct {
  double dt_s; int64_t n; int32_t want_fifo, fifo_priority, want_mlock, spin_ns;
  int64_t* late_ns; /* n wake-up latenesses */
  int32_t fifo_errno, mlock_errno;
} pp_probe;

static void* probe_run(void* arg) {
  pp_probe* P = (pp_probe*)arg;
  int64_t dt_ns = (int64_t)llround(P->dt_s * 1e9), t0, k;
  prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
  t0 = now_ns() + dt_ns;
  for (k = 0; k < P->n; ++k) {
    int64_t deadline = t0 + k * dt_ns;
    P->late_ns[k] = wait_until(deadline, P->spin_ns) - deadline;
  }
  return NULL;
}

/* run the probe to its end (blocking): SCHED_FIFO and locked memory where permitted, as the loop takes them */
int pp_probe_run(pp_probe* P) {
  pthread_t thread;
  int rc;
  P->mlock_errno = P->want_mlock ? (mlockall(MCL_CURRENT) ? errno : 0) : -1;
  rc = start_thread(&thread, P->want_fifo, P->fifo_priority, probe_run, P, &P->fifo_errno);
  if (rc == 0) rc = pthread_join(thread, NULL);
  if (P->mlock_errno == 0) munlockall();
  return rc;
}

int64_t pp_probe_sizeof(void) { return (int64_t)sizeof(pp_probe); }

/* the compiled controller step's compute time: n calls at (setpoint, pv), each timed, into ns */
int pp_time_step(pp_step_fn step, double setpoint, double pv, double* state, const double* params, int64_t n,
                 int64_t* ns) {
  double out[5];
  int64_t k, t;
  for (k = 0; k < n; ++k) {
    t = now_ns();
    if (step(setpoint, pv + 1e-3 * (double)(k & 7), 0.0, state, params, out)) return -1;
    ns[k] = now_ns() - t;
  }
  return 0;
}
