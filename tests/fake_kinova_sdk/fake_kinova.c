/* A fake of Kinova's Gen2 C SDK (Kinova.API.USBCommandLayerUbuntu.so) for the tests.
 *
 * It exports the functions hardware/kinova_gen2.py calls, with the signatures and struct layouts
 * of kinova-ros's kinova_driver/include/kinova/ (Kinova.API.USBCommandLayerUbuntu.h,
 * KinovaTypes.h, Kinova.API.USBCommLayerUbuntu.h). C++ references (`int &result`) are pointers
 * in the C ABI; structs taken by value (SendAdvanceTrajectory, SetActiveDevice) are by value here.
 *
 * It simulates one arm: the joints integrate the last ANGULAR_VELOCITY command (deg/s), which
 * expires `command_expiry` s (25 ms) after it was sent unless resent - the real arm's behaviour that
 * forces a 100 Hz sender. GetAngularVelocity reports half the real velocity, negative values
 * wrapped by +360 (the firmware quirk kinova-ros's driver undoes). Every call is recorded, with a
 * CLOCK_MONOTONIC timestamp (the clock of Python's time.perf_counter on Linux), into a ring buffer
 * read with FakeKinova_GetCall. Test-only functions (FakeKinova_*) add devices, inject a system
 * error, press the e-stop (actuator power cut: no motion, voltage 0, a voltage error logged) or
 * unplug the arm (every call fails with ERROR_NO_DEVICE_FOUND).
 *
 * Build: cc -shared -fPIC -O1 -o libfakekinova.so fake_kinova.c -lm -lpthread
 */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <stdbool.h>
#include <string.h>
#include <time.h>

#define NO_ERROR_KINOVA 1
#define ERROR_NO_DEVICE_FOUND 1015
#define ERROR_API_NOT_INITIALIZED 2101
#define ERROR_INVALID_PARAM 2100
#define SERIAL_LENGTH 20
#define MAX_KINOVA_DEVICE 20
#define ERROR_LAYER_COUNT 7
#define ERROR_DATA_COUNT_MAX 50
#define NJ 6

/* ---- KinovaTypes.h / Kinova.API.USBCommLayerUbuntu.h layouts (the fields used here) ---- */
typedef struct { char SerialNumber[SERIAL_LENGTH]; char Model[SERIAL_LENGTH]; int VersionMajor;
                 int VersionMinor; int VersionRelease; int DeviceType; int DeviceID; } KinovaDevice;
typedef struct { float Actuator1, Actuator2, Actuator3, Actuator4, Actuator5, Actuator6,
                 Actuator7; } AngularInfo;
typedef struct { float X, Y, Z, ThetaX, ThetaY, ThetaZ; } CartesianInfo;
typedef struct { float Finger1, Finger2, Finger3; } FingersPosition;
typedef struct { AngularInfo Actuators; FingersPosition Fingers; } AngularPosition;
typedef struct { float speedParameter1, speedParameter2, speedParameter3, forceParameter1,
                 forceParameter2, forceParameter3, accelerationParameter1,
                 accelerationParameter2, accelerationParameter3; } Limitation;
typedef struct { int Type; float Delay; CartesianInfo CartesianPosition; AngularInfo Actuators;
                 int HandMode; FingersPosition Fingers; } UserPosition;
typedef struct { UserPosition Position; int LimitationsActive; int SynchroType;
                 Limitation Limitations; } TrajectoryPoint;
typedef struct { float Voltage, Current, AccelerationX, AccelerationY, AccelerationZ,
                 ActuatorTemp1, ActuatorTemp2, ActuatorTemp3, ActuatorTemp4, ActuatorTemp5,
                 ActuatorTemp6, ActuatorTemp7, FingerTemp1, FingerTemp2, FingerTemp3; } SensorsInfo;
typedef struct { unsigned int ErrorHeader; int ErrorType; int FirmwareVersion; int KeosVersion;
                 unsigned int SystemTime; bool LayerErrorStatus[ERROR_LAYER_COUNT]; int LifeTime;
                 int DataCount; unsigned int Data[ERROR_DATA_COUNT_MAX]; } SystemError;

enum { ANGULAR_VELOCITY = 8 };
enum { errorlog_voltage = 9 };

/* ---- the call log ---- */
enum { F_INIT = 1, F_CLOSE, F_GET_DEVICES, F_SET_ACTIVE, F_START_CONTROL, F_STOP_CONTROL,
       F_SET_ANGULAR, F_SEND_TRAJ, F_ERASE, F_GET_POS, F_GET_VEL, F_GET_FORCE, F_GET_SENSORS,
       F_GET_ERR_COUNT, F_GET_ERR, F_REFRESH, F_GET_API_VERSION };

typedef struct { double t; int function; int result; int type; float values[7]; } FakeCall;

#define RING 262144
static FakeCall ring[RING];
static long ncalls = 0;

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static KinovaDevice devices[MAX_KINOVA_DEVICE];
static int ndevices = 0;
static int active = -1;
static bool initialized = false, control_on = false, angular = false, estop = false,
            unplugged = false;
static double q[NJ], cmd[NJ], cmd_time = -1.0, last_time = -1.0, command_expiry = 0.025;
static double voltage = 24.0;
static SystemError errors[64];
static unsigned int nerrors = 0;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void record(int function, int result, int type, const double *v) {
    FakeCall *c = &ring[ncalls % RING];
    c->t = now(); c->function = function; c->result = result; c->type = type;
    for (int i = 0; i < 7; i++) c->values[i] = (v != NULL && i < NJ) ? (float)v[i] : 0.0f;
    ncalls++;
}

/* Integrate the joints up to t: the command holds until it expires. */
static void advance(double t) {
    if (last_time < 0) { last_time = t; return; }
    if (t <= last_time) return;
    double end = t;
    if (cmd_time >= 0) {
        double expires = cmd_time + command_expiry;
        double until = end < expires ? end : expires;
        if (until > last_time && control_on && !estop)
            for (int i = 0; i < NJ; i++) q[i] += cmd[i] * (until - last_time);
    }
    last_time = t;
}

static double current_velocity(int i, double t) {
    if (cmd_time < 0 || t > cmd_time + command_expiry || !control_on || estop) return 0.0;
    return cmd[i];
}

static void log_error(int type) {
    if (nerrors >= 64) return;
    SystemError *e = &errors[nerrors++];
    memset(e, 0, sizeof(*e));
    e->ErrorHeader = nerrors; e->ErrorType = type; e->SystemTime = (unsigned int)(now() * 1e3);
}

static void zero_command(void) {
    for (int i = 0; i < NJ; i++) cmd[i] = 0.0;
    cmd_time = -1.0;
}

#define ENTER pthread_mutex_lock(&lock); double t_ = now(); advance(t_)
#define LEAVE(fn, res, type, v) do { int r_ = (res); record(fn, r_, type, v); \
    pthread_mutex_unlock(&lock); return r_; } while (0)
#define DEVICE_OK (initialized && !unplugged && active >= 0)

/* ---------------------------------------------------------------- the SDK's functions */
static bool environment_read = false;

/* For a fake used by another process (python -m ahrm_stack.deploy): FAKE_KINOVA_DEVICES
 * ("SERIAL:MODEL,SERIAL:MODEL") and FAKE_KINOVA_POSITION ("d1,...,d6", deg) are read once. */
static void read_environment(void) {
    if (environment_read) return;
    environment_read = true;
    const char *list = getenv("FAKE_KINOVA_DEVICES");
    if (list != NULL && ndevices == 0) {
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
}

int InitAPI(void) {
    ENTER; read_environment(); initialized = true; active = -1;
    LEAVE(F_INIT, unplugged || ndevices == 0 ? ERROR_NO_DEVICE_FOUND : NO_ERROR_KINOVA, 0, NULL);
}

int CloseAPI(void) {
    ENTER; initialized = false; control_on = false; active = -1; zero_command();
    LEAVE(F_CLOSE, NO_ERROR_KINOVA, 0, NULL);
}

int GetAPIVersion(int response[3]) {
    ENTER; response[0] = 5; response[1] = 2; response[2] = 0;
    LEAVE(F_GET_API_VERSION, NO_ERROR_KINOVA, 0, NULL);
}

int RefresDevicesList(void) {
    ENTER; LEAVE(F_REFRESH, initialized ? NO_ERROR_KINOVA : ERROR_API_NOT_INITIALIZED, 0, NULL);
}

int GetDevices(KinovaDevice list[MAX_KINOVA_DEVICE], int *result) {
    ENTER;
    int n = 0;
    if (!initialized) { *result = ERROR_API_NOT_INITIALIZED; }
    else if (unplugged) { *result = ERROR_NO_DEVICE_FOUND; }
    else {
        for (int i = 0; i < ndevices; i++) list[i] = devices[i];
        n = ndevices; *result = NO_ERROR_KINOVA;
    }
    record(F_GET_DEVICES, *result, n, NULL);
    pthread_mutex_unlock(&lock);
    return n;
}

int SetActiveDevice(KinovaDevice device) {
    ENTER;
    int found = -1;
    for (int i = 0; i < ndevices; i++)
        if (strncmp(devices[i].SerialNumber, device.SerialNumber, SERIAL_LENGTH) == 0) found = i;
    int result = (!initialized) ? ERROR_API_NOT_INITIALIZED
                 : (found < 0 || unplugged) ? ERROR_NO_DEVICE_FOUND : NO_ERROR_KINOVA;
    if (result == NO_ERROR_KINOVA) active = found;
    LEAVE(F_SET_ACTIVE, result, found, NULL);
}

int StartControlAPI(void) {
    ENTER; int ok = DEVICE_OK; if (ok) control_on = true;
    LEAVE(F_START_CONTROL, ok ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, NULL);
}

int StopControlAPI(void) {
    ENTER; int ok = DEVICE_OK; control_on = false; zero_command();
    LEAVE(F_STOP_CONTROL, ok ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, NULL);
}

int SetAngularControl(void) {
    ENTER; int ok = DEVICE_OK; if (ok) angular = true;
    LEAVE(F_SET_ANGULAR, ok ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, NULL);
}

int SendAdvanceTrajectory(TrajectoryPoint point) {
    ENTER;
    double v[NJ];
    const float *a = &point.Position.Actuators.Actuator1;
    for (int i = 0; i < NJ; i++) v[i] = a[i];
    int result = DEVICE_OK ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND;
    if (result == NO_ERROR_KINOVA && point.Position.Type == ANGULAR_VELOCITY && control_on
        && angular && !estop) {
        for (int i = 0; i < NJ; i++) cmd[i] = v[i];
        cmd_time = t_;
    }
    LEAVE(F_SEND_TRAJ, result, point.Position.Type, v);
}

int EraseAllTrajectories(void) {
    ENTER; int ok = DEVICE_OK; zero_command();
    LEAVE(F_ERASE, ok ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, NULL);
}

int GetAngularPosition(AngularPosition *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    float *a = &response->Actuators.Actuator1;
    for (int i = 0; i < NJ; i++) a[i] = (float)q[i];
    LEAVE(F_GET_POS, DEVICE_OK ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, q);
}

int GetAngularVelocity(AngularPosition *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    float *a = &response->Actuators.Actuator1;
    double v[NJ];
    for (int i = 0; i < NJ; i++) {
        v[i] = current_velocity(i, t_);
        double wrapped = v[i] < 0 ? v[i] + 360.0 : v[i];  /* 0..180 positive, 360..181 negative */
        a[i] = (float)(wrapped / 2.0);                     /* the firmware reports half */
    }
    LEAVE(F_GET_VEL, DEVICE_OK ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, v);
}

int GetAngularForce(AngularPosition *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    float *a = &response->Actuators.Actuator1;
    for (int i = 0; i < NJ; i++) a[i] = (float)(0.5 * (i + 1));  /* N m, any finite value */
    LEAVE(F_GET_FORCE, DEVICE_OK ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, NULL);
}

int GetSensorsInfo(SensorsInfo *response) {
    ENTER;
    memset(response, 0, sizeof(*response));
    response->Voltage = (float)(estop ? 0.0 : voltage);
    response->Current = 0.5f;
    response->ActuatorTemp1 = 30.0f;
    LEAVE(F_GET_SENSORS, DEVICE_OK ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, 0, NULL);
}

int GetSystemErrorCount(unsigned int *response) {
    ENTER; *response = nerrors;
    LEAVE(F_GET_ERR_COUNT, DEVICE_OK ? NO_ERROR_KINOVA : ERROR_NO_DEVICE_FOUND, (int)nerrors, NULL);
}

int GetSystemError(unsigned int index, SystemError *response) {
    ENTER;
    int ok = DEVICE_OK && index < nerrors;
    if (ok) *response = errors[index];
    LEAVE(F_GET_ERR, ok ? NO_ERROR_KINOVA : ERROR_INVALID_PARAM, (int)index, NULL);
}

/* ---------------------------------------------------------------- test-only functions */
void FakeKinova_Reset(void) {
    pthread_mutex_lock(&lock);
    ndevices = 0; active = -1; initialized = control_on = angular = estop = unplugged = false;
    for (int i = 0; i < NJ; i++) q[i] = 0.0;
    zero_command(); last_time = -1.0; command_expiry = 0.025; voltage = 24.0; nerrors = 0;
    ncalls = 0; environment_read = true;  /* the test configures this process's fake itself */
    pthread_mutex_unlock(&lock);
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

/* The true joint state, deg and deg/s. */
void FakeKinova_GetState(double *degrees, double *velocity) {
    pthread_mutex_lock(&lock);
    double t = now();
    advance(t);
    for (int i = 0; i < NJ; i++) { degrees[i] = q[i]; velocity[i] = current_velocity(i, t); }
    pthread_mutex_unlock(&lock);
}

void FakeKinova_SetCommandExpiry(double seconds) {
    pthread_mutex_lock(&lock); advance(now()); command_expiry = seconds; pthread_mutex_unlock(&lock);
}

/* A system error of the given errorLoggerType; the arm stops. */
void FakeKinova_InjectError(int type) {
    pthread_mutex_lock(&lock); advance(now()); log_error(type); zero_command();
    pthread_mutex_unlock(&lock);
}

/* The e-stop: actuator power cut (no motion, 0 V, a voltage error logged); released: power back. */
void FakeKinova_SetEStop(int pressed) {
    pthread_mutex_lock(&lock);
    advance(now());
    if (pressed && !estop) { log_error(errorlog_voltage); zero_command(); }
    estop = pressed != 0;
    pthread_mutex_unlock(&lock);
}

/* The USB cable pulled (every call fails) or put back. */
void FakeKinova_SetUnplugged(int value) {
    pthread_mutex_lock(&lock); advance(now()); unplugged = value != 0; if (unplugged) zero_command();
    pthread_mutex_unlock(&lock);
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

int FakeKinova_Initialized(void) {
    pthread_mutex_lock(&lock); int on = initialized; pthread_mutex_unlock(&lock); return on;
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
        default: return -1;
    }
}
