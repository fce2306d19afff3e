/* A fake of Kinova's Gen2 C SDK (USBCommandLayerUbuntu.so) for the tests, made to behave like the
 * arm behind a USB cable.
 *
 * It exports the functions ahrm_stack/hardware/kinova_gen2/sdk.py declares, with the signatures and struct layouts
 * of kinova-ros's kinova_driver/include/kinova/ (Kinova.API.USBCommandLayerUbuntu.h,
 * KinovaTypes.h, Kinova.API.USBCommLayerUbuntu.h). C++ references (`int &result`) are pointers
 * in the C ABI; structs taken by value (SendAdvanceTrajectory, SetActiveDevice) are by value here.
 *
 * What it models:
 * - USB round trips. Every SDK call blocks for `latency` s (FAKE_KINOVA_LATENCY_MS, default 3 ms)
 *   and the calls share one bus: a second caller waits for the first. Kinova's support
 *   (kinova-ros issue 233): the arm handles one message per 10 ms cycle, each blocking call takes
 *   "several ms", six calls can take more than 100 ms. Measured by a kinova-ros user (issue 372):
 *   over USB its status publisher, 9 SDK calls per cycle (kinova_arm.cpp statusTimer), tops out at
 *   40-60 Hz, i.e. 1.9-2.8 ms per call. 3 ms sits at the low end of "several ms" and just above
 *   that measurement: a fake that is not slower than the arm is the point.
 * - The trajectory FIFO. An ANGULAR_VELOCITY point (SendAdvanceTrajectory) joins a FIFO of 2,000
 *   points; the arm executes one point per 10 ms (100 Hz), back to back, and stands still when the
 *   FIFO is empty. Points sent slower than 100 Hz move the arm proportionally slower; points sent
 *   faster pile up and keep it moving after the sender stops, until EraseAllTrajectories empties
 *   the FIFO. A point arriving at a full FIFO is dropped (counted; the real code is not known).
 *   Pessimistic where the real arm is not documented: StopControlAPI, CloseAPI and a pulled cable
 *   do not empty the FIFO, nor does a logged system error; the e-stop (actuator power cut)
 *   stops the motion while pressed.
 * - Return codes without an arm, as Kinova's real x86_64 binary gives them (observed, kinova-ros
 *   kinova_driver/lib/x86_64-linux-gnu, libusb installed, no arm): see the table at
 *   `sdk_state`. SendAdvanceTrajectory and RefresDevicesList before InitAPI has loaded the
 *   communication layer crash the real SDK (SIGSEGV); the fake counts them (FakeKinova_Crashes) and,
 *   in a process that did not call FakeKinova_Reset or with FAKE_KINOVA_CRASH=1, crashes too.
 * - A cold boot (FAKE_KINOVA_COLD_BOOT=1, FakeKinova_SetColdBoot): the arm ignores the first
 *   StartControlAPI after power-up (control stays off) until StopControlAPI and StartControlAPI again,
 *   which is how this fake reads kinova-ros's "on a cold boot the arm may not respond to commands from
 *   the API right away" (kinova_comm.cpp, which starts, stops and starts the control API); the real
 *   symptom is not documented further.
 * - Position moves. An ANGULAR_POSITION point (SendAdvanceTrajectory) joins the same FIFO and moves
 *   the joints along a straight line in joint space to its target, each joint at most at its speed
 *   limit (LimitationsActive: speedParameter1 for joints 1-3, speedParameter2 for 4-6, deg/s, as
 *   kinova-ros's setJointAngles fills them; else DEFAULT_POSITION_SPEED), all arriving together;
 *   the next point starts when it arrives. MoveHome replaces the FIFO by one such move to the
 *   factory home (kinova-ros's j2n6s300 "Home", FakeKinova_SetHome to change) at the firmware's
 *   speed. EraseAllTrajectories stops either (assumed: Kinova documents neither).
 * - MoveHome blocks, as Kinova's binary does (disassembled; tests/test_kinova_gen2_move_home.py
 *   checks the vendored binary's instructions against this): it sends the home move (one packet),
 *   sleeps 40 ms, then reads GetGlobalTrajectoryInfo every 100 ms until the FIFO holds no point,
 *   then SetAngularControl, 40 ms, SetCartesianControl, and returns the home packet's code. So it
 *   returns only when the arm is home, or when something empties the FIFO (EraseAllTrajectories from
 *   another thread: each call holds the bus for one round trip, as the SDK's per-packet semaphore
 *   does), and leaves the arm in Cartesian control, where ANGULAR points are ignored here (assumed)
 *   until SetAngularControl. With the e-stop pressed the home move stays queued and MoveHome keeps
 *   polling. The log records MoveHome when its packet is sent.
 * - Joint torques. GetAngularForce reports what FakeKinova_SetForce set (N m; after a reset 0.5, 1.0,
 *   ..., 3.0): the fake has no dynamics, so a test that needs the torques of a held arm computes them
 *   (gravity at the fake's angles) and sets them, and a contact is a change of them.
 * - A runaway (FakeKinova_SetDrift): the joints move by themselves at a set speed whatever they are
 *   sent; only the e-stop stops them.
 * - Noisy velocity feedback. GetAngularVelocity reports the true velocity plus Gaussian noise
 *   (`velocity_noise` deg/s, FAKE_KINOVA_VELOCITY_NOISE, default 1 deg/s: an assumption; kinova-ros
 *   issues 366 and 381 report readings far from zero at rest and spiky in motion, without a figure),
 *   and exact angles by default (issue 366: "the joint angular positions is pretty good"; a noise
 *   of FakeKinova_SetPositionNoise deg, Gaussian, on request),
 *   at half the value with negative values wrapped by +360 (the firmware quirk kinova-ros's driver
 *   undoes).
 *
 * Every call is recorded, with CLOCK_MONOTONIC timestamps (the clock of Python's time.perf_counter
 * on Linux) of its start (before waiting for the bus) and its end, into a ring buffer read with
 * FakeKinova_GetCall. Test-only functions (FakeKinova_*) add devices, set the latency and the
 * noise, inject a system error, press the e-stop (actuator power cut: no motion, voltage 0, a
 * voltage error logged), unplug the arm or hide the communication layer (InitAPI: 2002).
 *
 * Build: cc -shared -fPIC -O1 -o libfakekinova.so fake_kinova.c -lm -lpthread
 */
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define NO_ERROR_KINOVA 1
#define ERROR_LOAD_USB_LIBRARY 1001
#define ERROR_NOT_INITIALIZED 1010
#define ERROR_NO_DEVICE_FOUND 1015
#define ERROR_LOAD_COMM_DLL 2002
#define JACO_COMM_FAILED 2004
#define ERROR_INVALID_PARAM 2100
#define ERROR_API_NOT_INITIALIZED 2101
#define SERIAL_LENGTH 20
#define MAX_KINOVA_DEVICE 20
#define ERROR_LAYER_COUNT 7
#define ERROR_DATA_COUNT_MAX 50
#define NJ 6
#define FIFO_SIZE 2000           /* points (Kinova Gen2: the trajectory FIFO's capacity) */
#define POINT_PERIOD 0.010       /* s: one point per control cycle, 100 Hz */
#define DEFAULT_LATENCY 0.003    /* s per SDK call: see the header comment */
#define DEFAULT_VELOCITY_NOISE 1.0  /* deg/s, standard deviation: an assumption (header comment) */
#define DEFAULT_POSITION_SPEED 20.0  /* deg/s per joint: MoveHome's, and an ANGULAR_POSITION point's
                                      * without limitations (an assumption: not documented) */

/* ---- KinovaTypes.h / Kinova.API.USBCommLayerUbuntu.h layouts (the fields used here) ---- */
typedef struct { char SerialNumber[SERIAL_LENGTH]; char Model[SERIAL_LENGTH]; int VersionMajor;
                 int VersionMinor; int VersionRelease; int DeviceType; int DeviceID; } KinovaDevice;
typedef struct { float Actuator1, Actuator2, Actuator3, Actuator4, Actuator5, Actuator6,
                 Actuator7; } AngularInfo;
typedef struct { float X, Y, Z, ThetaX, ThetaY, ThetaZ; } CartesianInfo;
/* QuickStatus: 14 unsigned chars (the vendored binary's DWARF); RobotType at offset 11 */
typedef struct { unsigned char Finger1Status, Finger2Status, Finger3Status, RetractType, RetractComplexity,
                 ControlEnableStatus, ControlActiveModule, ControlFrameType, CartesianFaultState,
                 ForceControlStatus, CurrentLimitationStatus, RobotType, RobotEdition,
                 TorqueSensorsStatus; } QuickStatus;
typedef struct { float Finger1, Finger2, Finger3; } FingersPosition;
typedef struct { AngularInfo Actuators; FingersPosition Fingers; } AngularPosition;
typedef struct { float speedParameter1, speedParameter2, speedParameter3, forceParameter1,
                 forceParameter2, forceParameter3, accelerationParameter1,
                 accelerationParameter2, accelerationParameter3; } Limitation;
typedef struct { int Type; float Delay; CartesianInfo CartesianPosition; AngularInfo Actuators;
                 int HandMode; FingersPosition Fingers; } UserPosition;
typedef struct { UserPosition Position; int LimitationsActive; int SynchroType;
                 Limitation Limitations; } TrajectoryPoint;
typedef struct { unsigned int TrajectoryCount; float UsedPercentage; unsigned int MaxSize; } TrajectoryFIFO;
typedef struct { float Voltage, Current, AccelerationX, AccelerationY, AccelerationZ,
                 ActuatorTemp1, ActuatorTemp2, ActuatorTemp3, ActuatorTemp4, ActuatorTemp5,
                 ActuatorTemp6, ActuatorTemp7, FingerTemp1, FingerTemp2, FingerTemp3; } SensorsInfo;
typedef struct { unsigned int ErrorHeader; int ErrorType; int FirmwareVersion; int KeosVersion;
                 unsigned int SystemTime; bool LayerErrorStatus[ERROR_LAYER_COUNT]; int LifeTime;
                 int DataCount; unsigned int Data[ERROR_DATA_COUNT_MAX]; } SystemError;

enum { ANGULAR_POSITION = 2, ANGULAR_VELOCITY = 8 };  /* POSITION_TYPE (KinovaTypes.h) */
enum { errorlog_voltage = 9 };

/* ---- the call log ---- */
enum { F_INIT = 1, F_CLOSE, F_GET_DEVICES, F_SET_ACTIVE, F_START_CONTROL, F_STOP_CONTROL,
       F_SET_ANGULAR, F_SEND_TRAJ, F_ERASE, F_GET_POS, F_GET_VEL, F_GET_FORCE, F_GET_SENSORS,
       F_GET_ERR_COUNT, F_GET_ERR, F_REFRESH, F_GET_API_VERSION, F_MOVE_HOME, F_GET_QUICK_STATUS,
       F_GET_GLOBAL_TRAJ, F_SET_CARTESIAN };

typedef struct { double t; int function; int result; int type; float values[7]; double start; } FakeCall;

#define RING 262144
static FakeCall ring[RING];
static long ncalls = 0;

static pthread_mutex_t bus = PTHREAD_MUTEX_INITIALIZER;   /* one USB round trip at a time */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;  /* the arm's state */

/* ---- the SDK's state, and what each function returns in it without an arm ----
 *
 * CLOSED, communication layer never loaded (before InitAPI, or InitAPI returned 2002):
 *   CloseAPI 1, EraseAllTrajectories 1, GetDevices 0 devices / result 2101, GetAngularPosition
 *   1010, every other getter and Set/Start/StopControlAPI 2101; SendAdvanceTrajectory and
 *   RefresDevicesList crash.
 * CLOSED after CloseAPI (the layer loaded before): the same, but SendAdvanceTrajectory 2101
 *   (RefresDevicesList: not observed; 2101 here).
 * OPEN without an arm (InitAPI returned 1015; a second InitAPI then returns 1): GetDevices
 *   0 / 1010, SetActiveDevice 1010, RefresDevicesList 1001, Start/StopControlAPI and
 *   SetAngularControl 1, SendAdvanceTrajectory 1 (2004 once GetDevices was called),
 *   EraseAllTrajectories 1, the getters 1015, CloseAPI 1.
 * OPEN with an arm: 1. A pulled cable (not observed): as without an arm, SendAdvanceTrajectory 2004. */
enum { CLOSED, OPEN_NO_DEVICE, OPEN };
static int sdk_state = CLOSED;
static bool comm_loaded = false, comm_missing = false, devices_listed = false;
static long crashes = 0;
static int fail_function = 0, fail_code = 0;  /* FakeKinova_FailNext */
static int crash_for_real = 1;

static KinovaDevice devices[MAX_KINOVA_DEVICE];
static int ndevices = 0;
static int active = -1;
static bool control_on = false, angular = false, estop = false, unplugged = false, cold = false;
static double latency = DEFAULT_LATENCY, velocity_noise = DEFAULT_VELOCITY_NOISE;
static double q[NJ], last_time = -1.0;
static double fifo[FIFO_SIZE][NJ];        /* a velocity point's deg/s, a position point's target deg */
static int fifo_type[FIFO_SIZE];          /* ANGULAR_VELOCITY or ANGULAR_POSITION */
static double fifo_speed[FIFO_SIZE][NJ];  /* a position point's joint speed limits, deg/s */
/* the factory home (MoveHome's target): j2n6s300's "Home" in kinova-ros's
 * kinova_moveit/robot_configs/j2n6s300_moveit_config/config/j2n6s300.srdf, rad -> deg */
static const double FACTORY_HOME[NJ] = {275.2885, 167.5800, 57.4104, 240.8247, 82.8383, 75.8196};
static double home_q[NJ], home_speed = DEFAULT_POSITION_SPEED, position_speed = DEFAULT_POSITION_SPEED;
static double drift[NJ];               /* deg/s the arm moves by itself (a runaway), whatever it is sent */
static double position_noise = 0.0;    /* deg, GetAngularPosition's noise (standard deviation) */
static double force[NJ];               /* N m, GetAngularForce's joint torques (FakeKinova_SetForce) */
static int fifo_head = 0, fifo_count = 0;
static double head_start = 0.0;  /* when the point at the head began (valid while fifo_count > 0) */
static long dropped = 0;
static int fifo_peak = 0;  /* the most points the FIFO held since FakeKinova_Reset */
static double voltage = 24.0;
static int robot_type = 3;  /* ROBOT_TYPE: JACOV2_6DOF_SERVICE, a j2n6s300 (FakeKinova_SetRobotType) */
static SystemError errors[64];
static unsigned int nerrors = 0;
static uint64_t rng = 0x9E3779B97F4A7C15ULL;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static double uniform(void) {  /* xorshift64*, in (0, 1) */
    rng ^= rng >> 12; rng ^= rng << 25; rng ^= rng >> 27;
    return ((double)((rng * 0x2545F4914F6CDD1DULL) >> 11) + 0.5) / 9007199254740992.0;
}

static double gaussian(void) { return sqrt(-2.0 * log(uniform())) * cos(6.283185307179586 * uniform()); }

static void record(int function, int result, int type, const double *v, double start) {
    FakeCall *c = &ring[ncalls % RING];
    c->t = now(); c->start = start; c->function = function; c->result = result; c->type = type;
    for (int i = 0; i < 7; i++) c->values[i] = (v != NULL && i < NJ) ? (float)v[i] : 0.0f;
    ncalls++;
}

/* s a position point needs from the joints' angles to its target, each joint at most at its speed,
 * all arriving together (a straight line in joint space) */
static double position_move_time(int index) {
    double longest = 0.0;
    for (int i = 0; i < NJ; i++) {
        double time = fabs(fifo[index][i] - q[i]) / fifo_speed[index][i];
        if (time > longest) longest = time;
    }
    return longest;
}

/* Integrate the joints up to t: the runaway's drift, then the FIFO's points back to back: a velocity
 * point for POINT_PERIOD, a position point until the joints reach its target. */
static void advance(double t) {
    if (last_time < 0) { last_time = t; return; }
    if (t <= last_time) return;
    if (!estop)
        for (int i = 0; i < NJ; i++) q[i] += drift[i] * (t - last_time);
    while (fifo_count > 0) {
        if (fifo_type[fifo_head] == ANGULAR_POSITION) {
            double from = last_time > head_start ? last_time : head_start;
            if (estop || t <= from) break;
            double need = position_move_time(fifo_head);
            if (need > t - from) {  /* on the way */
                double share = (t - from) / need;
                for (int i = 0; i < NJ; i++) q[i] += (fifo[fifo_head][i] - q[i]) * share;
                break;
            }
            for (int i = 0; i < NJ; i++) q[i] = fifo[fifo_head][i];  /* arrived at from + need */
            fifo_head = (fifo_head + 1) % FIFO_SIZE; fifo_count--;
            head_start = from + need;
            continue;
        }
        double end = head_start + POINT_PERIOD;
        double from = last_time > head_start ? last_time : head_start;
        double until = end < t ? end : t;
        if (until > from && !estop)
            for (int i = 0; i < NJ; i++) q[i] += fifo[fifo_head][i] * (until - from);
        if (end > t) break;
        fifo_head = (fifo_head + 1) % FIFO_SIZE; fifo_count--;
        head_start = end;
    }
    last_time = t;
}

static double current_velocity(int i) {
    if (estop) return 0.0;
    if (fifo_count == 0) return drift[i];
    if (fifo_type[fifo_head] == ANGULAR_POSITION) {
        double need = position_move_time(fifo_head);
        return drift[i] + (need > 0 ? (fifo[fifo_head][i] - q[i]) / need : 0.0);
    }
    return drift[i] + fifo[fifo_head][i];
}

static void erase_fifo(void) { fifo_head = 0; fifo_count = 0; }

/* A point joins the FIFO: `type` ANGULAR_VELOCITY (v: deg/s) or ANGULAR_POSITION (v: target deg,
 * speed: deg/s per joint). */
static void push_point(int type, const double *v, const double *speed, double t) {
    if (fifo_count >= FIFO_SIZE) { dropped++; return; }
    if (fifo_count == 0) head_start = t;
    int tail = (fifo_head + fifo_count) % FIFO_SIZE;
    fifo_type[tail] = type;
    for (int i = 0; i < NJ; i++) {
        fifo[tail][i] = v[i];
        fifo_speed[tail][i] = speed != NULL && speed[i] > 0 ? speed[i] : position_speed;
    }
    fifo_count++;
    if (fifo_count > fifo_peak) fifo_peak = fifo_count;
}

static void log_error(int type) {
    if (nerrors >= 64) return;
    SystemError *e = &errors[nerrors++];
    memset(e, 0, sizeof(*e));
    e->ErrorHeader = nerrors; e->ErrorType = type; e->SystemTime = (unsigned int)(now() * 1e3);
}

static void usb_round_trip(void) {
    if (latency <= 0) return;
    struct timespec ts = { (time_t)latency, (long)((latency - (double)(time_t)latency) * 1e9) };
    while (nanosleep(&ts, &ts) != 0) {}
}

/* What the real SDK does where it crashes (see the table above). */
static int crash(void) {
    crashes++;
    if (crash_for_real) raise(SIGSEGV);
    return ERROR_API_NOT_INITIALIZED;
}

#define ENTER double start_ = now(); pthread_mutex_lock(&bus); usb_round_trip(); \
    pthread_mutex_lock(&lock); double t_ = now(); advance(t_)
#define LEAVE(fn, res, type, v) do { int r_ = (res); \
    if (fail_function == (fn)) { r_ = fail_code; fail_function = 0; } \
    record(fn, r_, type, v, start_); \
    pthread_mutex_unlock(&lock); pthread_mutex_unlock(&bus); return r_; } while (0)
#define ARM (sdk_state == OPEN && !unplugged && active >= 0)   /* an arm answers */
/* a getter's code: 1 with an arm; 1015 open without one; 2101 (1010 for positions) closed */
#define GETTER(closed_code) (ARM ? NO_ERROR_KINOVA : sdk_state != CLOSED ? ERROR_NO_DEVICE_FOUND \
                             : (closed_code))
/* a command's code: 1 open (with or without an arm: the SDK does not wait for an answer), 2101 closed */
#define COMMAND (sdk_state != CLOSED ? NO_ERROR_KINOVA : ERROR_API_NOT_INITIALIZED)

/* ---------------------------------------------------------------- set-up from the environment */

/* For a fake used by another process (python -m ahrm_stack.deploy): FAKE_KINOVA_DEVICES
 * ("SERIAL:MODEL,SERIAL:MODEL"), FAKE_KINOVA_POSITION ("d1,...,d6", deg), FAKE_KINOVA_LATENCY_MS,
 * FAKE_KINOVA_VELOCITY_NOISE (deg/s), FAKE_KINOVA_HOME_SPEED (deg/s), FAKE_KINOVA_COMM_MISSING=1 (InitAPI: 2002) and
 * FAKE_KINOVA_CRASH (1, the default: crash where the real SDK crashes; 0: count only). */
__attribute__((constructor)) static void read_environment(void) {
    for (int i = 0; i < NJ; i++) home_q[i] = FACTORY_HOME[i];
    const char *home_speed_text = getenv("FAKE_KINOVA_HOME_SPEED");
    if (home_speed_text != NULL) home_speed = position_speed = atof(home_speed_text);
    const char *list = getenv("FAKE_KINOVA_DEVICES");
    if (list != NULL) {
        char buffer[512];
        strncpy(buffer, list, sizeof(buffer) - 1); buffer[sizeof(buffer) - 1] = 0;
        for (char *item = strtok(buffer, ","); item != NULL && ndevices < MAX_KINOVA_DEVICE;
             item = strtok(NULL, ",")) {
            char *colon = strchr(item, ':');
            if (colon != NULL) *colon = 0;
            KinovaDevice *d = &devices[ndevices];
            memset(d, 0, sizeof(*d));
            strncpy(d->SerialNumber, item, SERIAL_LENGTH - 1);
            strncpy(d->Model, colon != NULL ? colon + 1 : "JACO2", SERIAL_LENGTH - 1);
            d->DeviceID = 100 + ndevices++;
        }
    }
    const char *position = getenv("FAKE_KINOVA_POSITION");
    if (position != NULL) {
        double v[NJ];
        if (sscanf(position, "%lf,%lf,%lf,%lf,%lf,%lf", &v[0], &v[1], &v[2], &v[3], &v[4], &v[5]) == NJ)
            for (int i = 0; i < NJ; i++) q[i] = v[i];
    }
    const char *text = getenv("FAKE_KINOVA_LATENCY_MS");
    if (text != NULL) latency = atof(text) * 1e-3;
    text = getenv("FAKE_KINOVA_VELOCITY_NOISE");
    if (text != NULL) velocity_noise = atof(text);
    text = getenv("FAKE_KINOVA_COMM_MISSING");
    if (text != NULL) comm_missing = atoi(text) != 0;
    text = getenv("FAKE_KINOVA_CRASH");
    if (text != NULL) crash_for_real = atoi(text) != 0;
    text = getenv("FAKE_KINOVA_COLD_BOOT");
    if (text != NULL) cold = atoi(text) != 0;
}

/* ---------------------------------------------------------------- the SDK's functions */

int InitAPI(void) {
    ENTER;
    int result;
    if (comm_missing && !comm_loaded) result = ERROR_LOAD_COMM_DLL;
    else if (sdk_state != CLOSED) result = NO_ERROR_KINOVA;  /* observed: a second InitAPI says 1 */
    else {
        comm_loaded = true; devices_listed = false;
        bool found = ndevices > 0 && !unplugged;
        sdk_state = found ? OPEN : OPEN_NO_DEVICE;
        active = found ? 0 : -1;
        result = found ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND;
    }
    LEAVE(F_INIT, result, 0, NULL);
}

int CloseAPI(void) {
    ENTER; sdk_state = CLOSED; control_on = false; angular = false; active = -1; devices_listed = false;
    LEAVE(F_CLOSE, NO_ERROR_KINOVA, 0, NULL);
}

int GetAPIVersion(int response[3]) {
    ENTER; response[0] = 5; response[1] = 2; response[2] = 0;
    LEAVE(F_GET_API_VERSION, NO_ERROR_KINOVA, 0, NULL);
}

int RefresDevicesList(void) {
    ENTER;
    int result = sdk_state == CLOSED ? (comm_loaded ? ERROR_API_NOT_INITIALIZED : crash())
                 : ARM ? NO_ERROR_KINOVA : ERROR_LOAD_USB_LIBRARY;
    LEAVE(F_REFRESH, result, 0, NULL);
}

int GetDevices(KinovaDevice list[MAX_KINOVA_DEVICE], int *result) {
    ENTER;
    int n = 0;
    if (sdk_state == CLOSED) *result = ERROR_API_NOT_INITIALIZED;
    else if (sdk_state == OPEN_NO_DEVICE || unplugged) { *result = ERROR_NOT_INITIALIZED; devices_listed = true; }
    else {
        for (int i = 0; i < ndevices; i++) list[i] = devices[i];
        n = ndevices; *result = NO_ERROR_KINOVA;
    }
    record(F_GET_DEVICES, *result, n, NULL, start_);
    pthread_mutex_unlock(&lock);
    pthread_mutex_unlock(&bus);
    return n;
}

int SetActiveDevice(KinovaDevice device) {
    ENTER;
    int found = -1;
    for (int i = 0; i < ndevices; i++)
        if (strncmp(devices[i].SerialNumber, device.SerialNumber, SERIAL_LENGTH) == 0) found = i;
    int result = sdk_state == CLOSED ? ERROR_API_NOT_INITIALIZED
                 : (sdk_state == OPEN_NO_DEVICE || unplugged) ? ERROR_NOT_INITIALIZED
                 : found < 0 ? ERROR_NO_DEVICE_FOUND : NO_ERROR_KINOVA;
    if (result == NO_ERROR_KINOVA) active = found;
    LEAVE(F_SET_ACTIVE, result, found, NULL);
}

int StartControlAPI(void) {
    ENTER;
    int result = COMMAND;
    if (ARM && !cold) control_on = true;  /* after a cold boot the first start is ignored */
    LEAVE(F_START_CONTROL, result, 0, NULL);
}

int StopControlAPI(void) {
    ENTER; int result = COMMAND; if (ARM) { control_on = false; cold = false; }
    LEAVE(F_STOP_CONTROL, result, 0, NULL);
}

int SetAngularControl(void) {
    ENTER; int result = COMMAND; if (ARM) angular = true;
    LEAVE(F_SET_ANGULAR, result, 0, NULL);
}

int SendAdvanceTrajectory(TrajectoryPoint point) {
    ENTER;
    double v[NJ];
    const float *a = &point.Position.Actuators.Actuator1;
    for (int i = 0; i < NJ; i++) v[i] = a[i];
    int result;
    if (sdk_state == CLOSED) result = comm_loaded ? ERROR_API_NOT_INITIALIZED : crash();
    else if (!ARM) result = (devices_listed || unplugged) ? JACO_COMM_FAILED : NO_ERROR_KINOVA;
    else {
        result = NO_ERROR_KINOVA;
        if (point.Position.Type == ANGULAR_VELOCITY && control_on && angular && !estop)
            push_point(ANGULAR_VELOCITY, v, NULL, t_);
        if (point.Position.Type == ANGULAR_POSITION && control_on && angular && !estop) {
            /* kinova-ros setJointAngles: speedParameter1 limits joints 1-3, speedParameter2 the
             * others (deg/s), when LimitationsActive; else the firmware's own speed */
            double speed[NJ];
            for (int i = 0; i < NJ; i++)
                speed[i] = !point.LimitationsActive ? position_speed
                           : i < 3 ? point.Limitations.speedParameter1 : point.Limitations.speedParameter2;
            push_point(ANGULAR_POSITION, v, speed, t_);
        }
    }
    LEAVE(F_SEND_TRAJ, result, point.Position.Type, v);
}

/* The home packet: the FIFO is replaced by one move to home_q at home_speed (pessimistic where
 * undocumented: EraseAllTrajectories stops it, as any point). */
static int home_packet(void) {
    ENTER;
    int result = COMMAND;
    if (ARM && control_on && !estop) {
        double speed[NJ];
        for (int i = 0; i < NJ; i++) speed[i] = home_speed;
        erase_fifo();
        push_point(ANGULAR_POSITION, home_q, speed, t_);
    }
    LEAVE(F_MOVE_HOME, result, 0, home_q);
}

int GetGlobalTrajectoryInfo(TrajectoryFIFO *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA) {
        response->TrajectoryCount = (unsigned int)fifo_count;
        response->UsedPercentage = (float)(100.0 * fifo_count / FIFO_SIZE);
        response->MaxSize = FIFO_SIZE;
    }
    LEAVE(F_GET_GLOBAL_TRAJ, result, fifo_count, NULL);
}

int SetCartesianControl(void) {
    ENTER; int result = COMMAND; if (ARM) angular = false;
    LEAVE(F_SET_CARTESIAN, result, 0, NULL);
}

static void sleep_s(double seconds) {
    struct timespec ts = { (time_t)seconds, (long)((seconds - (double)(time_t)seconds) * 1e9) };
    while (nanosleep(&ts, &ts) != 0) {}
}

/* The factory home, as the joystick's home button, and as the vendored binary runs it (see the
 * header): the packet, 40 ms, then the FIFO polled every 100 ms until empty; then angular control,
 * 40 ms, Cartesian control. A failed read leaves the count 0 here (the binary's is not known). */
int MoveHome(void) {
    int result = home_packet();
    TrajectoryFIFO info;
    sleep_s(0.040);
    GetGlobalTrajectoryInfo(&info);
    while (info.TrajectoryCount != 0) {
        GetGlobalTrajectoryInfo(&info);
        sleep_s(0.100);
    }
    SetAngularControl();
    sleep_s(0.040);
    SetCartesianControl();
    return result;
}

int GetQuickStatus(QuickStatus *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA) {
        response->RobotType = (unsigned char)robot_type;
        response->ControlEnableStatus = control_on ? 1 : 0;
    }
    LEAVE(F_GET_QUICK_STATUS, result, robot_type, NULL);
}

int EraseAllTrajectories(void) {
    ENTER; if (ARM) erase_fifo();
    LEAVE(F_ERASE, NO_ERROR_KINOVA, 0, NULL);  /* 1 in every state observed */
}

int GetAngularPosition(AngularPosition *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    float *a = &response->Actuators.Actuator1;
    int result = GETTER(ERROR_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA)
        for (int i = 0; i < NJ; i++) a[i] = (float)(q[i] + (position_noise > 0 ? position_noise * gaussian() : 0.0));
    LEAVE(F_GET_POS, result, 0, q);
}

int GetAngularVelocity(AngularPosition *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    float *a = &response->Actuators.Actuator1;
    double v[NJ];
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    for (int i = 0; i < NJ; i++) {
        v[i] = current_velocity(i);
        double measured = v[i] + velocity_noise * gaussian();
        double wrapped = measured < 0 ? measured + 360.0 : measured;  /* negative: 360 - |v| */
        if (result == NO_ERROR_KINOVA) a[i] = (float)(wrapped / 2.0);  /* the firmware reports half */
    }
    LEAVE(F_GET_VEL, result, 0, v);
}

int GetAngularForce(AngularPosition *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    float *a = &response->Actuators.Actuator1;
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA) for (int i = 0; i < NJ; i++) a[i] = (float)force[i];
    LEAVE(F_GET_FORCE, result, 0, NULL);
}

int GetSensorsInfo(SensorsInfo *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA) {
        response->Voltage = (float)(estop ? 0.0 : voltage);
        response->Current = 0.5f;
        response->ActuatorTemp1 = 30.0f;
    }
    LEAVE(F_GET_SENSORS, result, 0, NULL);
}

int GetSystemErrorCount(unsigned int *response) {
    ENTER;
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA) *response = nerrors;  /* the real SDK leaves it as it was */
    LEAVE(F_GET_ERR_COUNT, result, (int)nerrors, NULL);
}

int GetSystemError(unsigned int index, SystemError *response) {
    ENTER;
    int result = GETTER(ERROR_API_NOT_INITIALIZED);
    if (result == NO_ERROR_KINOVA && index >= nerrors) result = ERROR_INVALID_PARAM;
    if (result == NO_ERROR_KINOVA) *response = errors[index];
    LEAVE(F_GET_ERR, result, (int)index, NULL);
}

/* ---------------------------------------------------------------- test-only functions */
/* A fresh fake for an in-process test: no device, no call recorded, defaults restored, and
 * would-be crashes counted instead of crashing the test process. */
void FakeKinova_Reset(void) {
    pthread_mutex_lock(&bus);
    pthread_mutex_lock(&lock);
    ndevices = 0; active = -1; sdk_state = CLOSED;
    control_on = angular = estop = unplugged = comm_loaded = comm_missing = devices_listed = cold = false;
    for (int i = 0; i < NJ; i++) q[i] = 0.0;
    erase_fifo(); dropped = 0; fifo_peak = 0; last_time = -1.0; voltage = 24.0; nerrors = 0; ncalls = 0;
    latency = DEFAULT_LATENCY; velocity_noise = DEFAULT_VELOCITY_NOISE; rng = 0x9E3779B97F4A7C15ULL;
    for (int i = 0; i < NJ; i++) { home_q[i] = FACTORY_HOME[i]; drift[i] = 0.0; force[i] = 0.5 * (i + 1); }
    home_speed = position_speed = DEFAULT_POSITION_SPEED; position_noise = 0.0;
    crashes = 0; crash_for_real = 0; fail_function = 0; robot_type = 3;
    pthread_mutex_unlock(&lock);
    pthread_mutex_unlock(&bus);
}

int FakeKinova_AddDevice(const char *serial, const char *model) {
    pthread_mutex_lock(&lock);
    int i = ndevices < MAX_KINOVA_DEVICE ? ndevices++ : -1;
    if (i >= 0) {
        memset(&devices[i], 0, sizeof(KinovaDevice));
        strncpy(devices[i].SerialNumber, serial, SERIAL_LENGTH - 1);
        strncpy(devices[i].Model, model, SERIAL_LENGTH - 1);
        devices[i].VersionMajor = 6; devices[i].DeviceID = 100 + i;
    }
    pthread_mutex_unlock(&lock);
    return i;
}

void FakeKinova_SetPosition(const double *degrees) {
    pthread_mutex_lock(&lock);
    advance(now());
    for (int i = 0; i < NJ; i++) q[i] = degrees[i];
    pthread_mutex_unlock(&lock);
}

/* The true joint state, deg and deg/s (no noise). */
void FakeKinova_GetState(double *degrees, double *velocity) {
    pthread_mutex_lock(&lock);
    advance(now());
    for (int i = 0; i < NJ; i++) { degrees[i] = q[i]; velocity[i] = current_velocity(i); }
    pthread_mutex_unlock(&lock);
}

/* MoveHome's target (deg) and joint speed (deg/s); the speed of position points without limitations. */
void FakeKinova_SetHome(const double *degrees, double speed) {
    pthread_mutex_lock(&lock);
    advance(now());
    for (int i = 0; i < NJ; i++) home_q[i] = degrees[i];
    home_speed = position_speed = speed;
    pthread_mutex_unlock(&lock);
}

/* A runaway: the joints move by themselves at `deg_s` (deg/s) from now, whatever is sent or erased
 * (0s: no drift); the e-stop (power cut) stops it. */
void FakeKinova_SetForce(const double *newton_metres) {  /* GetAngularForce's torques from now */
    pthread_mutex_lock(&lock);
    for (int i = 0; i < NJ; i++) force[i] = newton_metres[i];
    pthread_mutex_unlock(&lock);
}

void FakeKinova_SetDrift(const double *deg_s) {
    pthread_mutex_lock(&lock);
    advance(now());
    for (int i = 0; i < NJ; i++) drift[i] = deg_s[i];
    pthread_mutex_unlock(&lock);
}

/* deg, the standard deviation of GetAngularPosition's noise (0, the default: exact). */
void FakeKinova_SetPositionNoise(double degrees) {
    pthread_mutex_lock(&lock); position_noise = degrees; pthread_mutex_unlock(&lock);
}

/* s per SDK call (0: none). */
void FakeKinova_SetLatency(double seconds) {
    pthread_mutex_lock(&lock); latency = seconds; pthread_mutex_unlock(&lock);
}

/* deg/s, the standard deviation of GetAngularVelocity's noise (0: exact); `seed` restarts it. */
void FakeKinova_SetVelocityNoise(double deg_s, unsigned long long seed) {
    pthread_mutex_lock(&lock);
    velocity_noise = deg_s; rng = seed ? (uint64_t)seed : 0x9E3779B97F4A7C15ULL;
    pthread_mutex_unlock(&lock);
}

/* The points waiting in the FIFO, the executing one included; the most it held since the reset; the
 * points dropped when it was full. */
int FakeKinova_FifoCount(void) {
    pthread_mutex_lock(&lock); advance(now()); int n = fifo_count; pthread_mutex_unlock(&lock);
    return n;
}

int FakeKinova_FifoPeak(void) {
    pthread_mutex_lock(&lock); int n = fifo_peak; pthread_mutex_unlock(&lock); return n;
}

long FakeKinova_Dropped(void) {
    pthread_mutex_lock(&lock); long n = dropped; pthread_mutex_unlock(&lock); return n;
}

/* Calls that crash the real SDK (SendAdvanceTrajectory, RefresDevicesList before the
 * communication layer was loaded), counted since FakeKinova_Reset. */
long FakeKinova_Crashes(void) {
    pthread_mutex_lock(&lock); long n = crashes; pthread_mutex_unlock(&lock); return n;
}

/* InitAPI cannot load the communication layer (2002), as when it is not on the loader's path. */
void FakeKinova_SetCommMissing(int value) {
    pthread_mutex_lock(&lock); comm_missing = value != 0; pthread_mutex_unlock(&lock);
}

/* The next call of SDK function `function` (the call log's id) returns `code` (whatever it did). */
void FakeKinova_FailNext(int function, int code) {
    pthread_mutex_lock(&lock); fail_function = function; fail_code = code; pthread_mutex_unlock(&lock);
}

/* A system error of the given errorLoggerType is logged (the FIFO is left as it is: pessimistic). */
void FakeKinova_InjectError(int type) {
    pthread_mutex_lock(&lock); advance(now()); log_error(type); pthread_mutex_unlock(&lock);
}

/* The e-stop: actuator power cut (no motion while pressed, 0 V, a voltage error logged; the FIFO
 * runs on without moving the arm); released: power back. */
void FakeKinova_SetRobotType(int type) {
    pthread_mutex_lock(&lock);
    robot_type = type;
    pthread_mutex_unlock(&lock);
}

void FakeKinova_SetEStop(int pressed) {
    pthread_mutex_lock(&lock);
    advance(now());
    if (pressed && !estop) log_error(errorlog_voltage);
    estop = pressed != 0;
    pthread_mutex_unlock(&lock);
}

/* A cold boot: the next StartControlAPI is ignored until StopControlAPI (see the header). */
void FakeKinova_SetColdBoot(int value) {
    pthread_mutex_lock(&lock); cold = value != 0; pthread_mutex_unlock(&lock);
}

/* The USB cable pulled (the arm answers nothing; it finishes the points it holds) or put back. */
void FakeKinova_SetUnplugged(int value) {
    pthread_mutex_lock(&lock); advance(now()); unplugged = value != 0; pthread_mutex_unlock(&lock);
}

long FakeKinova_CallCount(void) {
    pthread_mutex_lock(&lock); long n = ncalls; pthread_mutex_unlock(&lock); return n;
}

/* Call `index` (0-based, in call order); 0 when it has been overwritten or not made yet. */
int FakeKinova_GetCall(long index, FakeCall *out) {
    pthread_mutex_lock(&lock);
    int ok = index >= 0 && index < ncalls && index >= ncalls - RING;
    if (ok) *out = ring[index % RING];
    pthread_mutex_unlock(&lock);
    return ok;
}

int FakeKinova_ControlOn(void) {
    pthread_mutex_lock(&lock); int on = control_on; pthread_mutex_unlock(&lock); return on;
}

/* 1 in angular control (SetAngularControl), 0 in Cartesian control (SetCartesianControl, MoveHome's end). */
int FakeKinova_Angular(void) {
    pthread_mutex_lock(&lock); int on = angular; pthread_mutex_unlock(&lock); return on;
}

int FakeKinova_Initialized(void) {
    pthread_mutex_lock(&lock); int on = sdk_state != CLOSED; pthread_mutex_unlock(&lock); return on;
}

/* sizeof of the SDK structs as this compiler lays them out (the ctypes layouts are checked). */
long FakeKinova_Sizeof(int which) {
    switch (which) {
        case 0: return (long)sizeof(KinovaDevice);
        case 1: return (long)sizeof(AngularPosition);
        case 2: return (long)sizeof(TrajectoryPoint);
        case 3: return (long)sizeof(SensorsInfo);
        case 4: return (long)sizeof(SystemError);
        case 5: return (long)sizeof(UserPosition);
        case 6: return (long)sizeof(TrajectoryFIFO);
        default: return -1;
    }
}
