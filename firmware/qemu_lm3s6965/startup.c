/* Start-up of the bridge firmware on QEMU's lm3s6965evb (Cortex-M3): the vector
 * table, the reset handler (stack painted for the high-water mark, .data
 * copied, .bss zeroed, C++ constructors run, then main) and the newlib stubs. */
#include <errno.h>
#include <stdint.h>
#include <sys/stat.h>

#define STACK_PAINT 0xA5A5A5A5u

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _stack_bottom, _stack_top;
extern int main(void);
extern void (*__init_array_start[])(void);
extern void (*__init_array_end[])(void);

void Reset_Handler(void);
void Default_Handler(void);
void Uart0_Handler(void);
void Uart1_Handler(void);
void Timer0A_Handler(void);

void Default_Handler(void) {
  for (;;) {
  }
}

/* 16 system exceptions, then the LM3S6965's 48 interrupts: UART0 5, UART1 6, Timer 0A 19. */
__attribute__((section(".vectors"), used)) static void (*const vectors[16 + 48])(void) = {
    (void (*)(void))(&_stack_top),
    Reset_Handler,
    Default_Handler, /* NMI */
    Default_Handler, /* HardFault */
    Default_Handler, /* MemManage */
    Default_Handler, /* BusFault */
    Default_Handler, /* UsageFault */
    0, 0, 0, 0,
    Default_Handler, /* SVCall */
    Default_Handler, /* DebugMon */
    0,
    Default_Handler, /* PendSV */
    Default_Handler, /* SysTick */
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Uart0_Handler, Uart1_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Timer0A_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
    Default_Handler, Default_Handler, Default_Handler, Default_Handler,
};

void Reset_Handler(void) {
  /* paint the stack below the live frame: the unpainted depth is the high-water mark */
  uint32_t sp;
  __asm volatile("mov %0, sp" : "=r"(sp));
  for (uint32_t *p = &_stack_bottom; (uint32_t)p < sp - 64; ++p) *p = STACK_PAINT;
  uint32_t *src = &_sidata;
  for (uint32_t *dst = &_sdata; dst < &_edata;) *dst++ = *src++;
  for (uint32_t *dst = &_sbss; dst < &_ebss;) *dst++ = 0;
  for (void (**f)(void) = __init_array_start; f < __init_array_end; ++f) (*f)(); /* C++ constructors */
  main();
  for (;;) {
  }
}

/* Bytes of the stack ever used (the deepest word no longer painted). */
uint32_t stack_high_water(void) {
  uint32_t *p = &_stack_bottom;
  while (p < &_stack_top && *p == STACK_PAINT) ++p;
  return (uint32_t)((uint8_t *)&_stack_top - (uint8_t *)p);
}

/* newlib: no heap (nothing here allocates; a call fails instead of growing), no files. */
void *_sbrk(int incr) {
  (void)incr;
  errno = ENOMEM;
  return (void *)-1;
}
int _close(int fd) { (void)fd; return -1; }
int _fstat(int fd, struct stat *st) { (void)fd; st->st_mode = S_IFCHR; return 0; }
int _isatty(int fd) { (void)fd; return 1; }
int _lseek(int fd, int off, int whence) { (void)fd; (void)off; (void)whence; return 0; }
int _read(int fd, char *buf, int n) { (void)fd; (void)buf; (void)n; return 0; }
int _write(int fd, const char *buf, int n) { (void)fd; (void)buf; return n; }
void _exit(int code) { (void)code; for (;;) { } }
int _kill(int pid, int sig) { (void)pid; (void)sig; return -1; }
int _getpid(void) { return 1; }
